"""`map_area`, the survey of thesis script 5.1, as a verb missions can call.

    enable("mapping")
    map_area(drone, 100*m, 80*m, 2, 4)                 # or run(map_area, drone, …)

From where the drone is (or from `init_pos`), it sweeps `x` metres east in `steps_x`
legs, shifts `y / steps_y` metres north, sweeps back west, and so on: `steps_y + 1`
traversals in all.
"""


def map_area(drone, x, y, steps_x, steps_y, init_pos=None):
    step_x = x / steps_x
    step_y = y / steps_y
    if init_pos is not None:
        move(drone, to=init_pos)
    for traversal in range(steps_y + 1):
        even = traversal % 2 == 0
        if traversal > 0:
            move(drone, right=step_y if even else -step_y)
        turn(drone, to=east if even else west)
        for _ in range(steps_x):
            move(drone, forward=step_x)


plugin(id="mapping", type=verbs, verbs=[map_area],
       doc="map_area(drone, x, y, steps_x, steps_y, init_pos=None): the lawnmower survey of thesis script 5.1.")
