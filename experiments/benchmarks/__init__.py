"""sfc-bench and its sections: speed, memory and fidelity figures printed side by side in one run."""
