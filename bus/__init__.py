"""The runtime seams shared by agent, ground and missions: the message bus and the clock.

`port.py` is the contract; `zenoh_bus.py` (real mesh) and `memory.py` (in-process, same
semantics) implement the Bus; `clock.py` gives real and virtual time.
"""
