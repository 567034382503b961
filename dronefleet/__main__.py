"""`python -m dronefleet …`: the same as the `fleet` console script."""

from dronefleet.launch import main

main()
