"""cassie (legged_gym terms), hand-written candidate: progress along the planar command.

Intent: a run that has not found a gait stands (or turns on the spot) and collects exp(-|c|^2 / 0.25) of
tracking_lin_vel, about 0.14 of its maximum at a 0.7 m/s command, a kernel that is flat far from the command.
This term pays linearly for the share of the commanded planar speed achieved along the command's
direction, clamped to [0, 1] so that overshooting earns nothing more: the first steps in the right direction
are paid as much per m/s as the last ones. Zero when the planar command is zero (standing is the tracking
terms' job). Scaled by the control step 0.02 s like every other Cassie term, so an episode that follows every
command collects at most 20, as tracking_lin_vel does.

obs["observation"] [N, 42]: columns 0:3 are the base linear velocity x 2 (base frame), columns 9:11 the planar
command (v_x, v_y) x 2.
"""

DT = 0.02  # s, the control step that scales every Cassie term
SCALE = 1.0


def compute_aux_reward(obs):
    velocity = obs["observation"][:, 0:2] * 0.5  # m/s, undoing the observation scale 2
    command = obs["observation"][:, 9:11] * 0.5  # m/s
    command_speed2 = (command * command).sum(-1)  # |c|^2
    # (v . c) / |c|^2: the fraction of the commanded speed achieved along its direction (|c| >= 0.2 when moving)
    progress = (velocity * command).sum(-1) / command_speed2.clamp(min=0.04)
    moving = (command_speed2 > 0.01).float()  # planar commands under 0.2 m/s are zeroed by the task
    return SCALE * DT * progress.clamp(0.0, 1.0) * moving
