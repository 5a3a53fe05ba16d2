"""The leaves every layer stands on: settings, constants, device arrays, exact host arithmetic,
memory estimates and the one resampler. Implements no paper section.

Nothing here imports anything of geosynth outside ``geosynth.core``.

- config.py       what does the environment say, and which state is process-wide? every environment
                  variable geosynth reads or sets and every module-level cache and lock, in two tables
- constants.py    why these tolerances and tuning values? each constant with its reason
- arrays.py       what is an array on a device? DeviceArray, the SELECT_* modes (imports nothing of geosynth)
- exact.py        host arithmetic with the same bits on every x86-64 CPU (issue 40)
- memory.py       will this run fit in memory? available_memory(), require(), MemoryBudgetError
- options.py      does an entry point take its settings as keywords or as one options object? settings_from()
- interpolate.py  what is a grid's value between samples? the one (bi/tri)linear resampler
- neighbours.py   which points are nearest? the one k-nearest-neighbour path (pykdtree; pairs by SciPy)

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
