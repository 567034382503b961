"""A field gas sensor raises the alarm; the nearest survey drone carrying a gas sensor
samples around it while an auxiliary drone relays (issue 35; thesis §7.2 items 2, 7).

The pole-mounted sensor gas07 stands 98 m from the laptop (examples/worlds/gas_alarm.yml).
The mission waits until a field gas sensor reads more than ALARM_PPM, then assigns the
nearest free drone with the survey role and a gas sensor (drone01 is nearer, but has
only a thermometer). It flies a ring of RING_POINTS around the sensor at RING_RADIUS,
reading its own `drone.sensor.gas.co_ppm` at each, and reports where the gas is
strongest: the side of the pole the leak lies on. Past the radio's good range the relay
plugin sends relays — auxiliary drones before survey drones (`any_relay`).

    fleet mission simulate examples/gas_alarm.py --world examples/worlds/gas_alarm.yml --out out/gas
"""

enable("relay", min_quality=0.6, step=4 * m, alt_diff=5 * m, base_alt=5 * m, ground=[40.634125, -8.660336])

ALARM_PPM = 50
RING_RADIUS = 15 * m
RING_POINTS = 8
ALTITUDE = 10 * m


def first_alarm():
    """The first field gas sensor reading over the threshold (waiting for readings)."""
    while True:
        for sensor in field_sensors(type="gas"):
            if sensor.value.co_ppm > ALARM_PPM:
                return sensor
        sleep(1 * s)


alarm = first_alarm()
print(f"alarm: {alarm.id} reads {alarm.value.co_ppm:.0f} ppm CO")
drone = assign(sensor="gas", role="survey", near=alarm)
arm(drone)
takeoff(drone, ALTITUDE)
strongest = None
for i in range(RING_POINTS):
    course = i * 360 / RING_POINTS
    spot = target(alarm.position, RING_RADIUS, course)
    move(drone, lat=spot.lat, lon=spot.lon, speed=5 * m / s)  # at its own height
    wait(drone)  # a reading taken where it now hovers
    reading = drone.sensor.gas.co_ppm
    print(f"{course:3.0f}° of {alarm.id}: {reading:.0f} ppm")
    if strongest is None or reading > strongest[0]:
        strongest = (reading, course)
print(f"strongest {strongest[0]:.0f} ppm at {strongest[1]:.0f}° of {alarm.id}: the leak lies that way")
move(drone, to=drone.home, speed=5 * m / s)
land(drone)
