"""Thesis script 5.4: the second drone starts only once the first has taken off.

`channel.done` is a single-assignment dataflow variable: reading it blocks routine2
until routine1 binds it.
"""


def routine1():
    arm(drone01)
    takeoff(drone01, 5 * m)
    channel.done = True
    for _ in range(6):
        move(drone01, left=12 * m, forward=3 * m)
    land(drone01)


def routine2():
    channel.done
    arm(drone02)
    takeoff(drone02, 2 * m)
    for _ in range(6):
        move(drone02, right=30 * m, forward=5 * m)
    land(drone02)


drone01 = assign("drone01")
drone02 = assign("drone02")
r1, r2 = run(routine1), run(routine2)
wait(r1, r2)
