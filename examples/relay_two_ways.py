"""Two drones working in different directions, kept connected by the relay plugin
(issue 15): drone01 flies 110 m south, drone02 110 m south-west (60° apart), both past
the radio's good range (60 m), hold there for 40 s and come back.

One relay between them serves both; the thesis's one chain per drone (mode="distance")
sends two relays after each.

    fleet mission simulate examples/relay_two_ways.py --world examples/worlds/relay_two_ways.yml
"""

enable("relay", ground=[40.634125, -8.660336])


def out_and_back(drone, heading, alt):
    arm(drone)
    takeoff(drone, alt)
    move(drone, to=target(drone.position, 110 * m, heading), speed=5 * m / s)
    sleep(40 * s)
    home(drone, alt)  # their ways home cross: each keeps its own height


south_one, south_west = assign("drone01"), assign("drone02")
wait(run(out_and_back, south_one, south, 15 * m), run(out_and_back, south_west, south + 60 * deg, 25 * m))
