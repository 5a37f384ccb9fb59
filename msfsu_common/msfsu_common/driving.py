"""Facts of driving that the control and the network's training share (one definition each)."""

# The control brakes to stand still below this desired speed (msfsu_control.pid's stop_speed default); a training
# label below it is a stop (the network's stop output, msfsu_perception.losses).
STOP_SPEED_MPS = 0.4
