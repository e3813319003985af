"""Simulated twins of the rig hardware, speaking the real bytes on loopback only.

Every twin runs in a background thread, binds only 127.0.0.1 (or a pty), takes a
:class:`fgloc.drivers.twins.faults.FaultConfig`, and is a context manager that shuts down
cleanly.
"""
