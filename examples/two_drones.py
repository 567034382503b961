"""Thesis script 5.3: two drones arm, take off, move and land at the same time."""


def dispatch(drone):
    arm(drone)
    takeoff(drone)


def land_drone(drone):
    land(drone)


drone01, drone02 = assign(any_drone, any_drone)
takeoff1, takeoff2 = run(dispatch, drone01), run(dispatch, drone02)
wait(takeoff1, takeoff2)
move1 = run(lambda: move(drone01, forward=10 * meters))
move2 = run(lambda: move(drone02, left=5 * meters))
wait(move1, move2)
land1, land2 = run(land_drone, drone01), run(land_drone, drone02)
wait(land1, land2)
