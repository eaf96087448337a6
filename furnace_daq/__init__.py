"""The plant-floor half: Modbus TCP and CAN sources, register decoding with quality, the MCAP
log, the polling daemon with its online refits, the simulated PLC, and replay.

It may import `furnace_model`; `furnace_model` never imports it.
"""
