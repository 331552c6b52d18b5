"""Frame sources and positions by time.

* A *frame source* yields frames with a name and a time: a video file (:mod:`.video`: PyAV, read frame by frame),
  a live stream (:mod:`.stream`: a URL or ``/dev/videoN``, paced by its clock), a ROS bag's image topic
  (:mod:`.bags`). Image folders and list files are listed by :mod:`seqnet.describe.images`, which reads all of
  these through one ``list_images``.
* *Positions by time* (:mod:`.tracks`; a bag's position topic: :mod:`.bags.positions`): GPX, NMEA 0183 and CSV
  tracks, joined to a video's clock, in metres, and
  interpolated at each frame's time (:mod:`.placed`: the frames of a video with their positions).
* :mod:`.sampling`: frames kept per second of video or per metre travelled.
"""
