"""Plants built on other engines (DESIGN.md §10). Each module imports its engine only
when it is imported itself: ``pkmctl.plants.mujoco`` needs ``pip install "pkmctl[mujoco]"``.
"""
