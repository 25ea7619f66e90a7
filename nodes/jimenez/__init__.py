"""Jimenez et al. 2010, *A Practical Appearance Model for Dynamic Facial Color* (seeds/jimenez2010_…)."""

NODES: dict[str, str] = {}
