"""Plants built on other engines (DESIGN.md §10). Each module imports its engine only
when it is imported itself: ``pkmctl.plants.mujoco`` needs ``pip install "mujoco>=3.1"`` (or
``pip install ".[mujoco]"`` in a checkout of pkmctl).

What a scenario needs to know of them without their engine lives here.
"""

#: The MuJoCo plant's equality-constraint softness: (time constant s, damping ratio) of
#: ``solref`` (:mod:`pkmctl.plants.mujoco`).
MUJOCO_SOLREF = (5e-4, 1.0)


def mujoco_max_timestep(solref: tuple[float, float] = MUJOCO_SOLREF) -> float:
    """The longest step (s) MuJoCo takes at the closures' time constant ``solref[0]``
    without raising it: half of it. MuJoCo raises a time constant under two steps to two
    steps (its "refsafe"), silently: at 1 ms the closures then took up their load 4x
    slower, the unforced machine gained 2.6e-4 J in 0.3 s and its pose left the closed
    form's by 1.2e-8 (a tester's oracle; 8e-11 J on the closed form)."""
    return solref[0] / 2 * (1 + 1e-9)
