"""`python -m dronefleet …`: the same as the `fleet` console script."""

from dronefleet.cli import main

main(prog_name="fleet")
