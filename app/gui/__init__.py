"""Rendering: the offscreen/windowed GGUI renderer (render.py), video files (video.py) and the
interactive viewer (viewer.py). Reads simulation fields only; never changes them except through
the viewer's controls, which call the same methods a script would."""
