"""The fire patrol as a task bundle (SPEC §6): the drone sweeps on its own, then the
mission traces the fire from the ground.

The sweep — a lawnmower of 40 m legs, 6 m apart, relative to where the drone stands —
is pushed to the drone in one piece with the guard `sensor.temperature > 37` on the
whole bundle: the drone ends the sweep by itself at the first hot reading, even if
the radio were down then, and `push` returns the drone's record of it. The mission
then traces the 40 °C contour step by step from the ground, as examples/fire_tracing.py
does (scripts cannot import each other: the tracing below is that example's).

    fleet mission simulate examples/fire_patrol_bundle.py --world examples/worlds/fire.yml --out out/patrol
"""

TARGET_TEMP = 40
DETECT_TEMP = 37
P, I, D = 8, 0.01, 10  # the thesis's empirically chosen gains
STEP = 4 * m
ON_CONTOUR = 2  # within this many °C of the target, the drone is on the contour
LOOP_TURN = 300  # degrees turned on the contour before the loop can close
MAX_TURN = 720  # degrees turned on the contour: give up closing the loop after two circles
LEG = 40 * m
SPACING = 6 * m
LEGS = 8


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
sweep = [step.takeoff(3 * m)]
for leg in range(LEGS):
    sweep.append(step.move(forward=LEG, speed=5 * m / s))
    sweep.append(step.move(right=SPACING if leg % 2 == 0 else -SPACING))
    sweep.append(step.turn(by=180 * deg))
patrol = push(drone, sweep, until=when.sensor.temperature > DETECT_TEMP, timeout=900 * s)
if patrol.state == "ended":
    print(f"the drone ended its sweep at step {patrol.step + 1}: {patrol.ended_by}")
    fly_out(drone)
    turn(drone, by=90 * deg)  # the fire ahead is then on the left
    trace(drone)
else:
    print(f"sweep {patrol.state} without finding the fire ({patrol.reason or 'no reading above'} {DETECT_TEMP} °C)")
home(drone)
