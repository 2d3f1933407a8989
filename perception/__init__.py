"""Perception: the RGB-D mesh tracker of Willimon et al. and its adapters."""
