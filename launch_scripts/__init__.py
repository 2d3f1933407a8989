"""Thin entry points that start the toolkit's processes."""
