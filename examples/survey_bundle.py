"""A survey beyond radio range, as a task bundle (SPEC §6, §8 lost link).

The area starts 120 m north of the laptop, past the radio's reach (examples/worlds/
survey.yml: messages thin out from 60 m, none get through from 100 m). The whole
flight — out, a lawnmower of 60 m legs 10 m apart, and home — is pushed to the drone
in one piece with `on_link_loss="continue"`: when the ground stops hearing it, the
drone goes on alone (its agent's own lost-link failsafe waits for the bundle), and the
mission waits for it (the bundle's timeout, then `mission.link_grace_s`) instead of
failing. Back in range, `push` returns the drone's record, every step of it, also
those done out of reach; the ground's log catches up the same way.

    fleet mission simulate examples/survey_bundle.py --world examples/worlds/survey.yml --out out/survey

With `on_link_loss="return"` instead, the drone gives up the survey when the link
drops and returns to launch; `push` then says it ended by "link lost".
"""

OUT = 120 * m  # the area's near edge, north of the laptop
LEG = 60 * m
SPACING = 10 * m
LEGS = 4  # an even number: the last leg ends on the west side, where the first began

drone = assign()
arm(drone)
survey = [step.takeoff(10 * m), step.move(forward=OUT, speed=8 * m / s)]
for leg in range(LEGS):
    survey.append(step.move(right=LEG if leg % 2 == 0 else -LEG, speed=5 * m / s))
    survey.append(step.move(forward=SPACING, speed=5 * m / s))
survey.append(step.home())  # out of range this far: the drone finds its way home alone
result = push(drone, survey, on_link_loss="continue", timeout=300 * s,
              until=when.battery.remaining_percent < 0.3)
print(f"survey {result.state}: {result.steps_done} of {result.steps} steps, "
      f"{len(result.history)} events in the drone's record")
if result.state != "done":
    print(f"the survey stopped at step {result.step + 1}: {result.ended_by or result.reason}")
    home(drone)
