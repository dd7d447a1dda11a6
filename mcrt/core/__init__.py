"""The render core: per-pixel statistics, atomic files, the pass engine, jobs and executors.

Everything above (render features, analysis, io, cli) builds on this package; it imports
nothing from them.
"""
