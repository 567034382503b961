"""The mission runtime: DSL verbs, units, assignment, subroutines, sandbox (SPEC §5)."""
