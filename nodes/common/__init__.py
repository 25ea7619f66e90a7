"""Maths shared by several papers' nodes (one implementation each)."""
