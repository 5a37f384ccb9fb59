"""Starts the MSFSU node graph from YAML profiles; rosbag2 MCAP player and recorder."""

# Bumped whenever a change to the node graph alters what a network does in a lockstep episode with the same route, seed
# and checkpoint; benchmark runs record it and never mix revisions for network agents (the expert drives in-process,
# without the graph). 1 (runs until 2026-11-27, unrecorded): a frame's images went out before its odometry and command,
# the control node took an action before the odometry published beside it (the speed of the frame before), the route
# node published on a sim-time timer, perception took whichever command had arrived last; 2: each frame's messages in
# order (clock, odometry, command, images), control takes odometry before actions, the route node answers each
# odometry, perception waits for its frame's command (`command_wait`); 3: every episode starts the graph fresh (each
# node's `~/reset` before the episode: the control's PID and steer limiter, the brake's tracks, the route's progress
# and perception's waiting frames no longer carry over from the episode before), and the control's watchdog waits for
# the first action (in revision 2 its brake at the first frame, stamped with that frame's time, could answer the frame
# in the network's place).
GRAPH_REVISION = 3
UNRECORDED_GRAPH_REVISION = 1  # what a run that recorded no graph revision drove its networks with
