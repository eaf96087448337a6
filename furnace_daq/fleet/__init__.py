"""Fleets of furnaces and years of logs: every batch job of the fleet on dask.distributed.

One concept per module:

- `description`: the fleet YAML (furnaces, their log directories, campaigns), checked at
  load with errors that name the key path.
- `engine`: the Dask client, on a LocalCluster of this machine's cores or on a running
  scheduler, the same code path either way.
- `tasks`: what a worker runs (scan a furnace's logs, refit one segment, diagnose one pair
  of campaigns, one selfcheck draw); each takes file paths and small settings and returns
  small plain tables.
- `store`: finished task results under the output directory, keyed by furnace and a hash
  of the input files and settings, so that a rerun skips what is done.
- `job`: what every job shares: plan, skip what is stored, fan out, gather, write tables.
- `jobs`: the jobs, one module each (refit, diagnose, selfcheck); the command line finds
  them there.
- `progress`: tasks done of total and failures, on a terminal or as lines for cron.
- `report`: the self-contained HTML fleet report.
"""
