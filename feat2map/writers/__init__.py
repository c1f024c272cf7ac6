"""Writers of the feat2map model into HD map formats and pictures."""
