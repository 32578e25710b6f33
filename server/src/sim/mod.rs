//! The force loop and the deformation loop, their shared state and recording.
