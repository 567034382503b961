"""Thesis script 5.1: map a 100 m x 80 m area with 2 x 4 steps, then land.

The drone sweeps left to right, bottom to top: each traversal flies `x` metres east
(or west) in `steps_x` legs, then shifts `y / steps_y` metres north.
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


drone01 = assign(any_drone)
arm(drone01)
takeoff(drone01)
map_area(drone01, 100 * m, 80 * m, 2, 4)
land(drone01)
