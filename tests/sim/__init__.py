"""The simulator: the vehicle model, the MAVLink vehicle as PX4 and ArduCopter, the
fast-time radio, scratch directories."""
