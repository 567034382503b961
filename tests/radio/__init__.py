"""Tests on real packets over the emulated radio (`fleet sim --agents --radio`, network
namespaces; CAP_NET_ADMIN, which CI as root has)."""
