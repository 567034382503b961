"""The mission script: the sandbox, units and geo, the drone view, channels, bundle
steps, the DSL verbs, plugins, and ScriptMission, which runs a script on a mission's
life cycle (mission/lifecycle)."""
