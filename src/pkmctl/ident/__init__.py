"""Identification of the dynamic parameters and the joint friction (DESIGN.md §9)."""
