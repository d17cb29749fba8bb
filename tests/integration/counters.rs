//! Counter truth end to end: wrap, resets, glitches, restarts, frequency.
