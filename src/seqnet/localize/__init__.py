"""Online localisation: the localiser, its stage and the track it writes."""
