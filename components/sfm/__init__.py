"""Structure-from-motion with pycolmap on the CPU: photos or video frames -> a COLMAP dataset (docs/export.md)."""
