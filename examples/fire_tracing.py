"""Thesis scripts 5.5 and 5.6: survey until it is hot, then trace the fire's perimeter.

A drone with a temperature sensor surveys the area (the bundled `mapping` plugin's
`map_area`, running as a subroutine). As soon as it reads more than 37 °C it stops
the survey, turns right a quarter (the fire, ahead, is then on its left; the thesis
left this to the survey's direction) and follows the 40 °C contour: every step it turns by a PID correction of
the temperature error (hotter than 40 °C → turn right, away from the fire on its
left; cooler → turn left, back towards it) and flies 4 m on. A drone that took off
inside the contour first flies straight out until it reads less than 40 °C. The loop
is closed when the drone comes back within 6 m of where it first reached the contour
(within 2 °C of the target) after turning most of a circle (300°) since; should it
never pass there again, it stops after turning two full circles. Then it returns home.

    fleet mission simulate examples/fire_tracing.py --world examples/worlds/fire.yml --out out/fire
"""

enable("mapping")
enable("contour")  # fly_out and trace_contour (mission/bundled/contour.py)

TARGET_TEMP = 40
DETECT_TEMP = 37


drone = assign(sensor="temperature")
arm(drone)
takeoff(drone, 3 * m)
survey = run(map_area, drone, 30 * m, 40 * m, 2, 3)
while survey.running:
    if drone.sensor.temperature > DETECT_TEMP:
        print(f"{drone.sensor.temperature:.1f} °C: tracing the {TARGET_TEMP} °C perimeter")
        stop(survey)
        fly_out(drone, TARGET_TEMP)
        # It got hotter along the way, so the fire lies ahead of the drone: a quarter
        # turn right puts it on the left, the side the controller keeps it on.
        turn(drone, by=90 * deg)
        trace_contour(drone, TARGET_TEMP)
        break
    wait(drone)
home(drone)
