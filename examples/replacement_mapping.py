"""Thesis script 5.2: mapping with a lazy drone replacement.

Before every leg the battery is checked; below 40 % the drone is sent home and a
fresh drone takes its place at the spot where the first one stopped, to finish.
The thesis wrote the swap out by hand (`run {home drone}; revoke drone;
summon_drone()`, then arm, take off, move to where the first one stopped);
`replace(drone)` does all of that — sends the drone home without waiting, releases
it, assigns the nearest free drone, which arms, takes off and flies to the spot,
facing the same way — keeping the same `drone` wrapper.

    fleet mission simulate examples/replacement_mapping.py --world examples/worlds/replacement.yml
"""

LOW_BATTERY = 0.4


def summon_drone():
    fresh = assign(any_drone)
    arm(fresh)
    takeoff(fresh)
    return fresh


def move_or_replace(**movement):
    if drone.battery < LOW_BATTERY:
        replace(drone)
    move(drone, **movement)


def map_area(x, y, steps_x, steps_y):
    step_x = x / steps_x
    step_y = y / steps_y
    for traversal in range(steps_y + 1):
        even = traversal % 2 == 0
        if traversal > 0:
            move_or_replace(right=step_y if even else -step_y)
        turn(drone, to=east if even else west)
        for _ in range(steps_x):
            move_or_replace(forward=step_x)


drone = summon_drone()
map_area(100 * m, 80 * m, 3, 3)
land(drone)
