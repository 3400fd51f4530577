//! SynthNOCS benchmark generator (in progress).
