"""Thesis script 6.1: a survey with the replacement plugin enabled.

The `replacement` plugin watches every drone of the mission: when the battery needed
to fly home (0.15 % per metre here) plus a 25 % reserve exceeds what is left, the
drone goes home and the closest free drone takes over where it stopped; the survey
(the bundled `mapping` plugin's `map_area`) goes on as if nothing happened. The
second drone is not replaced on its way home: it is then moving to its home.

    fleet mission simulate examples/mapping_with_replacement.py --drones 2 --out out/replacement
"""

enable("replacement", drainage=0.0015)
enable("mapping")


def summon_drone():
    fresh = assign(any_drone)
    arm(fresh)
    takeoff(fresh)
    return fresh


drone = summon_drone()
finish_map = run(map_area, drone, 100 * m, 75 * m, 2, 3, position(40.6330, -8.6604))
wait(finish_map)
move(drone, lat=drone.home.lat, lon=drone.home.lon, speed=10)
land(drone)
