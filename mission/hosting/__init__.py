"""Where missions run: the manager and its SQLite records, isolation in a worker
process (the worker's side and its frames), fast-time simulation and plots."""
