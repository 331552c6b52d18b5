"""Sequence matchers (one registry), SeqMatch, velocity-robust and graph matching, HVPR."""
