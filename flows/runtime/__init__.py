"""What runs beside a command (design §10): the Dask workers' stage calls (:mod:`.workers`), the
watchdog that ends a command's services with it (:mod:`.reaper`) and its stdio guard
(:mod:`.guard`), the record of a run in Prefect (:mod:`.history`), Prefect tasks that cost nothing
until a flow runs (:mod:`.lazy_prefect`) and the compiled kernels' warm-up (:mod:`.warmup`)."""
