"""Fault injection: link faults on each receiver's inbox, process faults, their summary."""
