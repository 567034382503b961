"""The fire patrol as a task bundle (SPEC §6): the drone sweeps on its own, then the
mission traces the fire from the ground.

The sweep — a lawnmower of 40 m legs, 6 m apart, relative to where the drone stands —
is pushed to the drone in one piece with the guard `sensor.temperature > 37` on the
whole bundle: the drone ends the sweep by itself at the first hot reading, even if
the radio were down then, and `push` returns the drone's record of it. The mission
then traces the 40 °C contour step by step from the ground with the bundled `contour`
plugin, as examples/fire_tracing.py does.

    fleet mission simulate examples/fire_patrol_bundle.py --world examples/worlds/fire.yml --out out/patrol
"""

enable("contour")  # fly_out and trace_contour (mission/bundled/contour.py)

TARGET_TEMP = 40
DETECT_TEMP = 37
LEG = 40 * m
SPACING = 6 * m
LEGS = 8


drone = assign(sensor="temperature")
arm(drone)
sweep = [step.takeoff(3 * m)]
for leg in range(LEGS):
    sweep.append(step.move(forward=LEG, speed=5 * m / s))
    sweep.append(step.move(right=SPACING if leg % 2 == 0 else -SPACING))
    sweep.append(step.turn(by=180 * deg))
patrol = push(drone, sweep, until=when.sensor.temperature > DETECT_TEMP, timeout=900 * s)
if patrol.state == "ended":
    print(f"the drone ended its sweep at step {patrol.step + 1}: {patrol.ended_by}")
    fly_out(drone, TARGET_TEMP)
    turn(drone, by=90 * deg)  # the fire ahead is then on the left
    trace_contour(drone, TARGET_TEMP)
else:
    print(f"sweep {patrol.state} without finding the fire ({patrol.reason or 'no reading above'} {DETECT_TEMP} °C)")
home(drone)
