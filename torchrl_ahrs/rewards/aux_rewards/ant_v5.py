"""ant_v5 (Gymnasium Ant-v5 on EnvPool): torso height and uprightness keeping.

Intent: Ant-v5 is unhealthy (episode ends) outside a torso height of [0.2, 1.0] m; a dense bonus for a
standing height while the torso's up axis points up rewards the posture from which running is learnt.

obs["observation"] [N, 105]: column 0 is the torso height z (m), columns 1:5 the torso quaternion (w, x, y, z).
"""

SCALE = 0.25  # a quarter of the survive bonus
LOW_HEIGHT = 0.2  # m, unhealthy below
GOOD_HEIGHT = 0.5  # m


def compute_aux_reward(obs):
    observation = obs["observation"]
    height = observation[:, 0]
    qx = observation[:, 2]
    qy = observation[:, 3]
    # z component of the torso's up axis for a unit quaternion: 1 - 2 (qx^2 + qy^2)
    up = (1.0 - 2.0 * (qx * qx + qy * qy)).clamp(0.0, 1.0)
    standing = ((height - LOW_HEIGHT) / (GOOD_HEIGHT - LOW_HEIGHT)).clamp(0.0, 1.0)
    return SCALE * standing * up
