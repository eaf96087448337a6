"""The files a fleet job writes under --out that others read: the report reads the refit's
and the diagnosis's tables, the command line names them. Kept apart from the report (which
loads pandas) so that a job module stays light for `furnace-daq fleet --help`."""

REPORT = "fleet_report.html"
REFIT = "refit.parquet"
DRIFT_EVENTS = "drift_events.parquet"
REFIT_FAILURES = "refit_failures.parquet"
VERDICTS = "verdicts.parquet"
DIAGNOSE_FAILURES = "diagnose_failures.parquet"
