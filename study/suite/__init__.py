"""The SecUAV benchmark suites: versioned sets of study files (``secuav-study suite``); see docs/bench.md."""
