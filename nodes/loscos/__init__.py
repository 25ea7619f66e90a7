"""Loscos, Drettakis, Robert 2000, *Interactive Virtual Relighting of Real Scenes* (seeds/loscos2000_…)."""

NODES: dict[str, str] = {}
