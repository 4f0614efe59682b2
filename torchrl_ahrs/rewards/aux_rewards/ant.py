"""ant (Isaac Gym reward): torso height keeping.

Intent: the ant dies (-2, episode ends) when its torso drops below 0.31 m; a dense bonus that grows with
the torso height between 0.31 m and 0.55 m teaches it to stay up on its legs before it learns to run.

obs["observation"] [N, 37]: column 0 is the torso height z (m).
"""

SCALE = 0.25  # half the alive bonus at full height
DEATH_HEIGHT = 0.31  # m, the task's termination height
GOOD_HEIGHT = 0.55  # m, standing on its legs


def compute_aux_reward(obs):
    height = obs["observation"][:, 0]
    # 0 at the death height, 1 from a standing height up
    return SCALE * ((height - DEATH_HEIGHT) / (GOOD_HEIGHT - DEATH_HEIGHT)).clamp(0.0, 1.0)
