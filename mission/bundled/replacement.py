"""Replace a drone whose battery will not bring it home (thesis script 5.7).

After every telemetry update of every drone of the mission: the battery needed to fly
home is `drainage` (battery fraction per metre) times the distance home; when that
plus `min_battery` exceeds what is left, the drone is replaced by the closest free
one, which takes over where it stopped. A drone already on its way home — returning,
or moving to a point within 50 cm of its home — is left alone.

    enable("replacement", drainage=0.0015)
"""


def needed_battery(drone):
    return drainage * drone.distance(drone.home)


def returning_home(drone):
    cmd = drone.cmd
    if cmd is None:
        return False
    if cmd.name == "return":
        return True
    return cmd.name == "goto" and cmd.target is not None and cmd.distance(drone.home) < 50 * cm


def main(drone):
    if drone.home is None or returning_home(drone):
        return
    if needed_battery(drone) > drone.battery - min_battery:
        print(f"{drone.id}: needs {needed_battery(drone):.1%} to fly home, has {drone.battery:.1%} (keeping {min_battery:.0%})")
        replace(drone)


plugin(id="replacement", type=monitoring,
       input={"min_battery": (float, 0.25), "drainage": (float, 0.0002)},
       callback=main,
       doc="Replace a drone when the battery to fly home plus min_battery exceeds what it has.")
