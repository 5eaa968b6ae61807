"""The interactive side: ``motionweb app``, a long-lived local service and its web page.

``engine`` keeps the committed generation's webs in memory and answers queries (KG04 §3.3-4.1);
``api`` is the FastAPI app over it; ``recorder`` records every query as a Prefect flow run;
``server`` runs it all (uvicorn, the Prefect server, the discovery file); ``client`` lets the
CLI send its queries to a running service; ``static/`` is the page.
"""
