"""Thesis scripts 5.5 and 5.6: survey until it is hot, then trace the fire's perimeter.

A drone with a temperature sensor surveys the area (the bundled `mapping` plugin's
`map_area`, running as a subroutine). As soon as it reads more than 37 °C it stops
the survey, turns right a quarter (the fire, ahead, is then on its left; the thesis
left this to the survey's direction) and follows the 40 °C contour: every step it turns by a PID correction of
the temperature error (hotter than 40 °C → turn right, away from the fire on its
left; cooler → turn left, back towards it) and flies 4 m on. Once it has been more
than 7 m from where the tracing began and comes back within 5 m, the loop is closed
and it returns home.

    fleet mission simulate examples/fire_tracing.py --world examples/worlds/fire.yml --out out/fire
"""

enable("mapping")

TARGET_TEMP = 40
DETECT_TEMP = 37
P, I, D = 8, 0.01, 10  # the thesis's empirically chosen gains
STEP = 4 * m


def trace(drone, start):
    error_sum = 0
    previous = None
    left_start = False
    while True:
        wait(drone)  # the reading after this telemetry was taken where the drone is now
        error = drone.sensor.temperature - TARGET_TEMP
        change = 0 if previous is None else error - previous
        correction = P * error + I * error_sum + D * change
        error_sum += error
        previous = error
        course = (drone.heading + correction) % 360
        move(drone, to=drone.target(STEP, course), yaw=course, speed=10 * m / s)
        if not left_start:
            left_start = drone.distance(start) > 7 * m
        elif drone.distance(start) < 5 * m:
            print("perimeter traced: back where the tracing began")
            break


drone = assign(sensor="temperature")
arm(drone)
takeoff(drone, 3 * m)
survey = run(map_area, drone, 30 * m, 40 * m, 2, 3)
while survey.running:
    if drone.sensor.temperature > DETECT_TEMP:
        print(f"{drone.sensor.temperature:.1f} °C: tracing the {TARGET_TEMP} °C perimeter")
        start = drone.position
        stop(survey)
        # It got hotter along the way, so the fire lies ahead of the drone: a quarter
        # turn right puts it on the left, the side the controller keeps it on.
        turn(drone, by=90 * deg)
        trace(drone, start)
        break
    wait(drone)
home(drone)
