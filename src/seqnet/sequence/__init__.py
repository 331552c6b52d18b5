"""Windows of frames, sequence descriptors (single, smoothing, Delta, SeqNet S_L / S_1) and model files."""
