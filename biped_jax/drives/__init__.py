"""Motors and gearheads: the drive model and catalogue, the drive-train selection."""
