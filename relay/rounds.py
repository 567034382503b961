"""When the relay plugin plans: once per round of the drones it hears, and not more often
than a period (pure code, no I/O).

The plugin is called on every telemetry sample of every drone of the mission. A plan
per sample would plan as often as the chattiest drone speaks, and a drone in doubt of
the ground speaks four times as often (every 250 ms, ADR 0003): counted in plans, relays
were sent home four times as fast (the plugin sends one home after a number of plans
that found it not needed), and a drone went unheard for 4 s. So a round ends when a
drone is heard a second time since the last plan (a drone out of reach does not hold
the round open), and a new plan needs `every_s` since the last one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

PLAN_EVERY_S = 0.9  # plans at most this often: a drone in doubt of the ground speaks every 250 ms


@dataclass
class PlanRounds:
    every_s: float = PLAN_EVERY_S
    heard: list[str] = field(default_factory=list)  # drones heard since the last plan
    planned_at: float | None = None  # when the last plan was

    def due(self, drone_id: str, now: float) -> bool:
        """`drone_id` was heard at `now`: True when a plan is due (and it counts as made)."""
        if drone_id not in self.heard:
            self.heard.append(drone_id)
            return False
        if self.planned_at is not None and now - self.planned_at < self.every_s:
            return False
        self.heard, self.planned_at = [drone_id], now
        return True
