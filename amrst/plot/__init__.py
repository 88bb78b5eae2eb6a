"""A forest plot: its scans registered by their stems, and every tree measured."""
