"""Thesis script 5.1: map a 100 m x 80 m area with 2 x 4 steps, then land.

The survey is `map_area` from the bundled `mapping` plugin (mission/bundled/mapping.py,
the thesis's function as written there): the drone sweeps left to right, bottom to
top — each traversal flies `x` metres east (or west) in `steps_x` legs, then shifts
`y / steps_y` metres north.
"""

enable("mapping")

drone01 = assign(any_drone)
arm(drone01)
takeoff(drone01)
map_area(drone01, 100 * m, 80 * m, 2, 4)
land(drone01)
