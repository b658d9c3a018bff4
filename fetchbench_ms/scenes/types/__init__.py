"""One module per scene type; importing this package registers them all."""
