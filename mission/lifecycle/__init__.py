"""A mission's life cycle, knowing nothing of scripts: its record and causes, the
subroutine scheduler, drone assignment, the mission shell (events, link grace, the
end) and command delivery. The script layer (mission/script) runs on top of it."""
