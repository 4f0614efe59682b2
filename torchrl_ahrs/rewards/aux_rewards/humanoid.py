"""humanoid (Gymnasium Humanoid-v5 on EnvPool): torso height keeping.

Intent: the humanoid is unhealthy below a torso height of 1.0 m; a dense bonus that grows from 1.0 m to
1.3 m (standing) rewards staying tall, the posture that forward walking needs.

obs["observation"] [N, 348]: column 0 is the torso height z (m).
"""

SCALE = 1.0  # a fifth of the survive bonus (5 per step)
LOW_HEIGHT = 1.0  # m
GOOD_HEIGHT = 1.3  # m


def compute_aux_reward(obs):
    height = obs["observation"][:, 0]
    return SCALE * ((height - LOW_HEIGHT) / (GOOD_HEIGHT - LOW_HEIGHT)).clamp(0.0, 1.0)
