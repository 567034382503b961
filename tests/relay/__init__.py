"""Relays (issues 15, 32, 53): the planner, chains and ways as pure logic, the corpus,
the experiments and the first world a user writes, in fast time."""
