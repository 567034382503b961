"""Message shapes of the Fleet wire contract (SPEC §2) and key-expression helpers.

No I/O lives here: only msgspec Structs, their typed decoders, key building and the
great-circle maths every component shares.
"""
