"""The modular puppet device: protocol, serial reader, rig reduction (arrives with the device issue)."""
