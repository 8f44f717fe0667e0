"""A trained lifter at work: loaded as a function (`inference`), people followed through frames
(`tracking`), and the figures of what it lifted (`lifting_figures`)."""
