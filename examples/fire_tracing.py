"""Thesis scripts 5.5 and 5.6: survey until it is hot, then trace the fire's perimeter.

A drone with a temperature sensor surveys the area (the bundled `mapping` plugin's
`map_area`, running as a subroutine). As soon as it reads more than 37 °C it stops
the survey, turns right a quarter (the fire, ahead, is then on its left; the thesis
left this to the survey's direction) and follows the 40 °C contour: every step it turns by a PID correction of
the temperature error (hotter than 40 °C → turn right, away from the fire on its
left; cooler → turn left, back towards it) and flies 4 m on. A drone that took off
inside the contour first flies straight out until it reads less than 40 °C. The loop
is closed when the drone comes back within 6 m of where it first reached the contour
(within 2 °C of the target) after turning most of a circle (300°) since; should it
never pass there again, it stops after turning two full circles. Then it returns home.

    fleet mission simulate examples/fire_tracing.py --world examples/worlds/fire.yml --out out/fire
"""

enable("mapping")

TARGET_TEMP = 40
DETECT_TEMP = 37
P, I, D = 8, 0.01, 10  # the thesis's empirically chosen gains
STEP = 4 * m
ON_CONTOUR = 2  # within this many °C of the target, the drone is on the contour
LOOP_TURN = 300  # degrees turned on the contour before the loop can close
MAX_TURN = 720  # degrees turned on the contour: give up closing the loop after two circles


def turned_by(old, new):
    """The signed change of course from `old` to `new`, in (-180, 180] degrees."""
    return (new - old + 180) % 360 - 180


def fly_out(drone):
    """From inside the contour, straight on until it is cooler than the target."""
    while drone.sensor.temperature > TARGET_TEMP:
        move(drone, to=drone.target(STEP, drone.heading), speed=10 * m / s)
        wait(drone)


def trace(drone):
    error_sum = 0
    previous = None
    start = None  # where the drone first reached the contour
    turned = 0  # degrees turned since then
    last_course = None
    while True:
        wait(drone)  # the reading after this telemetry was taken where the drone is now
        error = drone.sensor.temperature - TARGET_TEMP
        change = 0 if previous is None else error - previous
        correction = P * error + I * error_sum + D * change
        error_sum += error
        previous = error
        course = (drone.heading + correction) % 360
        if start is None and abs(error) < ON_CONTOUR:
            start = drone.position
        elif start is not None:
            turned += turned_by(last_course, course)
        last_course = course
        move(drone, to=drone.target(STEP, course), yaw=course, speed=10 * m / s)
        if start is None:
            continue
        if abs(turned) >= LOOP_TURN and drone.distance(start) < 1.5 * STEP:
            print("perimeter traced: back where it reached the contour")
            break
        if abs(turned) >= MAX_TURN:
            print("perimeter traced: two full circles without passing the start again")
            break


drone = assign(sensor="temperature")
arm(drone)
takeoff(drone, 3 * m)
survey = run(map_area, drone, 30 * m, 40 * m, 2, 3)
while survey.running:
    if drone.sensor.temperature > DETECT_TEMP:
        print(f"{drone.sensor.temperature:.1f} °C: tracing the {TARGET_TEMP} °C perimeter")
        stop(survey)
        fly_out(drone)
        # It got hotter along the way, so the fire lies ahead of the drone: a quarter
        # turn right puts it on the left, the side the controller keeps it on.
        turn(drone, by=90 * deg)
        trace(drone)
        break
    wait(drone)
home(drone)
