"""shadow_hand_bottle_cap: keep the bottle upright and turn the cap, before the fingers are in place.

Intent: the lift term pays only once the five right fingertips are within 0.3 m (summed) of the cap, and a
toppled bottle ends the episode; rewarding the bottle's uprightness and the cap's twist (capped at 3 rad,
the 0.03 m of rise that counts as success) gives a signal for holding the bottle steady and for turning
the cap however the hand reaches it.

obs["observation"] [N, 213]: right hand (95), left hand (95), bottle pose (7: position, quaternion w x y z
at 193), linear velocity (3), angular velocity x 0.2 (3), bottle, cap seat and cap positions (9), cap twist (1, at 212).
"""

UPRIGHT_SCALE = 0.3
TWIST_SCALE = 0.3


def compute_aux_reward(obs):
    observation = obs["observation"]
    quat = observation[:, 193:197]
    up_z = 1.0 - 2.0 * (quat[:, 1] * quat[:, 1] + quat[:, 2] * quat[:, 2])  # z of the bottle axis in the world
    twist = observation[:, 212].clamp(0.0, 3.0) / 3.0
    return UPRIGHT_SCALE * up_z + TWIST_SCALE * twist
