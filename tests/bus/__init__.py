"""The bus (SPEC §2): the memory and Zenoh adapters under one contract, key expressions,
sockets, the datagram echo, the loop watch, and traffic a stock Zenoh tool reads."""
