"""Simulated vehicles and world: one vehicle model behind the agent's `sim` adapter,
the PX4-like MAVLink endpoint and fast-time simulation."""
