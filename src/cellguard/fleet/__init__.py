"""Fleet: fault signatures pooled across sites under each customer's data policy.

    signature     one finding as it may leave a site (effect sizes, versions; no raw values)
    policy        the customer's data policy file; export enforces it and builds the batch
    audit         the site's append-only log of exports; outbox holds batches the store did not take
    push          one push: outbox first (each batch checked against the policy in force), audit, send
    store         PostgreSQL with per-tenant login roles and forced row-level security
    queries       the named queries, one SQL text for DuckDB, Spark and PostgreSQL
    lake          signatures as Parquet partitioned by date and tenant; duckdb_engine, spark_engine
    similar       the nearest signatures from other sites and what fixed them
"""
