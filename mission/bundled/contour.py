"""Following a contour of a sensor's field, the fire tracing of thesis scripts 5.5 and 5.6,
as verbs missions can call.

    enable("contour")
    fly_out(drone)                   # from inside the contour, straight on until cooler
    turn(drone, by=90*deg)           # the fire ahead is then on the left
    trace_contour(drone)             # follow the 40 °C contour until the loop closes

`trace_contour` turns the drone every step by a PID correction of the temperature
error (hotter than `target` → turn right, away from the fire on its left; cooler →
turn left, back towards it) and flies `step` on. The loop is closed when the drone
comes back within 1.5 steps of where it first reached the contour (within
`on_contour` °C of the target) after turning `loop_turn` degrees since; should it
never pass there again, it stops after turning `max_turn` degrees.
"""


def turned_by(old, new):
    """The signed change of course from `old` to `new`, in (-180, 180] degrees."""
    return (new - old + 180) % 360 - 180


def fly_out(drone, target=40, step=None):
    """From inside the contour, straight on until it is cooler than `target`."""
    step = 4 * m if step is None else step
    while drone.sensor.temperature > target:
        move(drone, to=drone.target(step, drone.heading), speed=10 * m / s)
        wait(drone)


def trace_contour(drone, target=40, step=None, gains=(8, 0.01, 10), on_contour=2, loop_turn=300, max_turn=720):
    """Follow the `target` contour with the fire on the left until the loop closes.
    `gains`: the thesis's empirically chosen P, I, D."""
    step = 4 * m if step is None else step
    p, i, d = gains
    error_sum = 0
    previous = None
    start = None  # where the drone first reached the contour
    turned = 0  # degrees turned since then
    last_course = None
    while True:
        wait(drone)  # the reading after this telemetry was taken where the drone is now
        error = drone.sensor.temperature - target
        change = 0 if previous is None else error - previous
        correction = p * error + i * error_sum + d * change
        error_sum += error
        previous = error
        course = (drone.heading + correction) % 360
        if start is None and abs(error) < on_contour:
            start = drone.position
        elif start is not None:
            turned += turned_by(last_course, course)
        last_course = course
        move(drone, to=drone.target(step, course), yaw=course, speed=10 * m / s)
        if start is None:
            continue
        if abs(turned) >= loop_turn and drone.distance(start) < 1.5 * step:
            print("perimeter traced: back where it reached the contour")
            break
        if abs(turned) >= max_turn:
            print("perimeter traced: two full circles without passing the start again")
            break


plugin(id="contour", type=verbs, verbs=[fly_out, trace_contour],
       doc="fly_out(drone, target=40) and trace_contour(drone, target=40, step=4*m, gains=(8, 0.01, 10), …): "
           "the fire tracing of thesis scripts 5.5-5.6.")
