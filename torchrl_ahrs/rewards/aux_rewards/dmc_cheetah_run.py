"""dmc_cheetah_run: do not flip.

Intent: a common local optimum of cheetah run is flipping onto its back and running upside down; a
penalty that grows with the torso pitch beyond 45 degrees keeps the body the right way up.

obs["position"] [N, 8]: generalised positions without the x coordinate; column 1 is the torso pitch (rad).
"""

import math

SCALE = 0.1
FREE_PITCH = math.pi / 4  # rad: no penalty inside this range


def compute_aux_reward(obs):
    pitch = obs["position"][:, 1].abs()
    return -SCALE * (pitch - FREE_PITCH).clamp(0.0, math.pi)
