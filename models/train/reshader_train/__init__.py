"""reshader's training toolchain: dataset rendering, training, export."""
