"""The walking step's dynamics: single support and impact in MJX, the planar chain in closed form."""
