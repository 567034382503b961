"""The top layer: the `fleet` command line and the composition root.

Everything below (schemas < bus < sim < agent, mission < ground) is wired together
here and only here: `compose.run_ground` for `fleet ground`, `compose.SimField` for
fast-time simulation, `demo` for `fleet demo`. The order is checked by import-linter
(`make lint`, contract in pyproject.toml).
"""
