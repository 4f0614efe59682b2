"""dmc_quadruped_run: run straight.

Intent: the move term pays forward speed only; sideways drift wastes effort and leads towards the
arena's edge. A small penalty on the torso's lateral velocity keeps the run straight.

obs["torso_velocity"] [N, 3]: torso velocity in its own frame (forward, lateral, vertical), m/s.
"""

SCALE = 0.05
MAX_PENALTY = 0.5


def compute_aux_reward(obs):
    lateral = obs["torso_velocity"][:, 1]
    return -(SCALE * lateral * lateral).clamp(0.0, MAX_PENALTY)
