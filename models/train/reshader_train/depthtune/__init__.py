"""Fine-tuning the depth network on rendered photos with true depth (`train-depth`,
`export-depth`)."""
