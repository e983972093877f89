"""Plants built on other engines (DESIGN.md §10). Each module imports its engine only
when it is imported itself: ``pkmctl.plants.mujoco`` needs ``pip install "mujoco>=3.1"`` (or
``pip install ".[mujoco]"`` in a checkout of pkmctl).
"""
