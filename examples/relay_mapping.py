"""Thesis script 6.2: drone01 maps a far area while the relay plugin keeps it connected.

The area (50 m by 50 m from its corner at 40.632963, -8.660440) lies 80-135 m south of
the ground station: past the radio's good range (60 m), its far side past 100 m where
nothing gets through (examples/worlds/relay.yml). The plugin dispatches
relay drones from the free ones as drone01 flies out, moves them as it maps, and
sends them home when it comes back.

    fleet mission simulate examples/relay_mapping.py --world examples/worlds/relay.yml --out out/relay
"""

enable("relay", min_quality=0.6, step=4 * m, alt_diff=5 * m, base_alt=5 * m, ground=[40.634125, -8.660336])
enable("mapping")
drone = assign("drone01")
arm(drone)
takeoff(drone)
map_area(drone, 50 * m, 50 * m, 1, 3, position(40.632963, -8.660440))
move(drone, to=drone.home, speed=3 * m / s)
land(drone)
