"""Mission scripts and worlds that users copy from, installed with Fleet as the
`dronefleet.examples` package so that `fleet demo` and a user without the source tree find
them: `python -c "from dronefleet import examples; print(examples.DIR)"`. The scripts are
mission DSL (SPEC §5), run by the mission runtime, never imported."""

from pathlib import Path

DIR = Path(__file__).resolve().parent
WORLDS = DIR / "worlds"
