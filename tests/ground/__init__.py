"""The ground station: its API and registry, recovery, commands routed to drones, two
grounds on one mesh (SPEC §14), security (SPEC §9), recordings (SPEC §12) and map tiles."""
