"""ROS bags (ROS 1 ``.bag``, ROS 2 folders, MCAP) as sources: :mod:`.images` (an image topic as frames named by
their timestamps) and :mod:`.positions` (a NavSatFix / Odometry / PoseStamped topic as positions by time). Every
file rosbags opens is checked first (:mod:`seqnet.security.bagfiles`)."""
