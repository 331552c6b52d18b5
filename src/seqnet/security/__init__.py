"""The guarded boundary: every file seqnet reads or writes goes through this package (docs/security.md).

Readers of untrusted files: :mod:`.inputs` (opening, paths read from files, names), :mod:`.arrays` (npy, npz),
:mod:`.jsonfile`, :mod:`.limits` (numbers), :mod:`.unpickle`, :mod:`.torchfile`; libraries that can crash or
follow other files run in a sandboxed child (:mod:`.sandbox`, :mod:`.child`): :mod:`.hdf5file`, :mod:`.faissfile`,
:mod:`.matlab` (after :mod:`.matfile` checks its bytes); :mod:`.bagfiles` (ROS bags), :mod:`.pictures` (images).
Writers: :mod:`.files` (atomic writes), :mod:`.dirs`, :mod:`.folders`, :mod:`.locks`, :mod:`.ownership`,
:mod:`.digests`; text out: :mod:`.text`.
"""
