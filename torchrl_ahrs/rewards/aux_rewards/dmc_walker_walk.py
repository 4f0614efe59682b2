"""dmc_walker_walk: steady torso.

Intent: the walker falls when its torso pitches fast; a small penalty on the torso's pitch rate keeps
the upper body steady while the standing, upright and move terms drive the gait.

obs["velocity"] [N, 9]: generalised velocities; column 2 is the torso pitch rate (rad/s).
"""

SCALE = 0.002  # random flailing: about -0.03 per step against a total of about 0.15
MAX_PENALTY = 1.0


def compute_aux_reward(obs):
    pitch_rate = obs["velocity"][:, 2]
    return -(SCALE * pitch_rate * pitch_rate).clamp(0.0, MAX_PENALTY)
