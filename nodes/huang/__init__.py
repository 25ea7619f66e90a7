"""Huang et al. 2013, *Physically based cosmetic rendering* (seeds/huang2013_…)."""

NODES: dict[str, str] = {}
