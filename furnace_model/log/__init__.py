"""The acquisition log: its topics and schemas, reading MCAP files whole or salvaged, and
resampling them to the tabular contract. Both packages use it: the daemon writes what these
modules define, and every reader reads through them.

This file imports nothing: `furnace-daq --help` reads the topics without loading numpy.
"""
