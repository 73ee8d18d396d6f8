"""A drone multispectral capture (one file per band, one lens per band) as a rig: reading, registering, scoring."""
