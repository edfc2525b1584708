"""A User-mode Linux guest with SocketCAN ``vcan0`` up, for a host whose kernel has none
(containers, WSL, CI runners): :mod:`.vm` boots one and runs a command in it, :mod:`.kernel`
chooses, probes and fetches the kernel it boots (docs/virtual_bus.md). ``python -m
virtual_bus guest`` is its command; ``dev.py test`` runs the tests marked vcan in it."""
