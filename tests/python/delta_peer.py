"""Independent readers of a dataset's Delta Lake table (tests/delta.rs): the `deltalake` package, Polars and
DuckDB (through deltalake's pyarrow dataset: DuckDB's wheel has no delta extension offline).

  rows TABLE [VERSION]      every row, read with deltalake (DeltaTable(TABLE, version=VERSION)): the scalar
                            columns and the point lists, value by value
  polars TABLE              the same rows read with Polars: pl.scan_delta on the columns it reads natively,
                            and pl.read_delta(use_pyarrow=True) for the point lists (see the README)
  duckdb TABLE SQL          DuckDB over DeltaTable(TABLE).to_pyarrow_dataset() as `pairs`: the result rows
  info TABLE [VERSION]      version, schema (column -> Delta type), add actions (path -> num_records), history length
  corrupt TABLE FILE        changes one byte of the shard file's footer (its created_by string): another blake3,
                            still a Parquet file with the same rows

TABLE is a folder, an s3:// URL or an az:// URL. For s3:// the endpoint and keys come from AWS_ENDPOINT_URL,
AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY and AWS_REGION (never the instance metadata service); az:// is a
local Azurite in object_store's emulator mode (AZURITE_BLOB_STORAGE_URL, Azurite's published development
account). Rows are printed as a JSON list of {column: value}, one per row as the reader returned it
(duplicates kept: the caller counts them).
"""
import json
import os
import sys

COLUMNS = ["pair_key", "unit_index", "seed", "status", "overlap_source", "overlap_target", "target_view", "target_known_share"]
POINTS = ["source_points", "target_points"]

# Azurite's well-known development account (public, documented; not a secret).
AZURITE_ACCOUNT = "devstoreaccount1"
AZURITE_KEY = "Eby8vdM02xNOcqFlqUwJPLlmEtlCDXJ1OUzFT50uSRZ6IFsuFq2UVErCz4I6tq/K1SZFPTOtr/KBHBeksoGMGw=="


def storage(table):
    if table.startswith("az://"):
        # Emulator mode: the blob endpoint comes from AZURITE_BLOB_STORAGE_URL.
        return {
            "azure_storage_account_name": AZURITE_ACCOUNT,
            "azure_storage_account_key": AZURITE_KEY,
            "azure_storage_use_emulator": "true",
        }
    if not table.startswith("s3://"):
        return None
    return {
        "aws_endpoint_url": os.environ["AWS_ENDPOINT_URL"],
        "aws_access_key_id": os.environ["AWS_ACCESS_KEY_ID"],
        "aws_secret_access_key": os.environ["AWS_SECRET_ACCESS_KEY"],
        "aws_region": os.environ.get("AWS_REGION", "us-east-1"),
        "aws_allow_http": "true",
    }


def delta_table(table, version=None):
    from deltalake import DeltaTable

    return DeltaTable(table, version=None if version is None else int(version), storage_options=storage(table))


def rows(table, version=None):
    return delta_table(table, version).to_pyarrow_table().select(COLUMNS + POINTS).to_pylist()


def polars_rows(table):
    import polars as pl

    # Polars' own Parquet reader refuses the fixed-size lists (points, poses) under Delta's `array` type;
    # every other column reads natively. The point lists read through deltalake's pyarrow dataset, joined
    # by row position (both readers list the table's files in the log's order).
    native = pl.scan_delta(table, storage_options=storage(table)).select(COLUMNS).collect().to_dicts()
    whole = pl.read_delta(table, storage_options=storage(table), use_pyarrow=True).select(["pair_key"] + POINTS).to_dicts()
    assert len(native) == len(whole), f"polars: {len(native)} rows natively, {len(whole)} through pyarrow"
    out = []
    for a, b in zip(sorted(native, key=lambda r: r["pair_key"]), sorted(whole, key=lambda r: r["pair_key"])):
        assert a["pair_key"] == b["pair_key"], (a["pair_key"], b["pair_key"])
        out.append({**a, **{c: b[c] for c in POINTS}})
    return out


def duckdb_rows(table, sql):
    import duckdb

    pairs = delta_table(table).to_pyarrow_dataset()  # noqa: F841 (DuckDB finds it by name)
    return [list(r) for r in duckdb.sql(sql).fetchall()]


def delta_type(t):
    """Delta's type name of a deltalake schema type (primitive name, array<...>, struct<...>)."""
    kind = getattr(t, "type", None)
    if kind == "array":
        return f"array<{delta_type(t.element_type)}>"
    if kind == "struct":
        return "struct<" + ", ".join(f"{f.name}: {delta_type(f.type)}" for f in t.fields) + ">"
    return str(kind)


def info(table, version=None):
    import pyarrow as pa

    dt = delta_table(table, version)
    adds = pa.table(dt.get_add_actions(flatten=True)).to_pydict()
    return {
        "version": dt.version(),
        "schema": {f.name: delta_type(f.type) for f in dt.schema().fields},
        "nullable": [f.name for f in dt.schema().fields if f.nullable],
        "files": dict(zip(adds["path"], adds["num_records"])),
        "history": len(dt.history()),
    }


def corrupt(table, file):
    """Flips the case of the first byte of the footer's `created_by` ("pointreggpt ... (parquet-rs)")."""
    if table.startswith("s3://"):
        import boto3

        bucket, _, prefix = table[len("s3://"):].partition("/")
        s3 = boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL"], region_name=os.environ.get("AWS_REGION", "us-east-1"))
        key = f"{prefix}/{file}" if prefix else file
        data = bytearray(s3.get_object(Bucket=bucket, Key=key)["Body"].read())
    else:
        path = os.path.join(table, file)
        with open(path, "rb") as f:
            data = bytearray(f.read())
    at = data.rfind(b"pointreggpt ")
    assert at > 0, "no created_by string in the footer"
    data[at] ^= 0x20
    if table.startswith("s3://"):
        s3.put_object(Bucket=bucket, Key=key, Body=bytes(data))
    else:
        with open(path, "wb") as f:
            f.write(data)
    return at


def main():
    os.environ["AWS_EC2_METADATA_DISABLED"] = "true"
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "rows":
        result = rows(*args)
    elif cmd == "polars":
        result = polars_rows(*args)
    elif cmd == "duckdb":
        result = duckdb_rows(*args)
    elif cmd == "info":
        result = info(*args)
    elif cmd == "corrupt":
        result = corrupt(*args)
    else:
        sys.exit(f"unknown command {cmd}")
    print(json.dumps(result, sort_keys=True))
    # deltalake's and Polars' native threads can abort the interpreter's teardown with "terminate called
    # without an active exception" after the answer is printed (delta-io/delta-rs#2184, pola-rs/polars#24169;
    # seen once in 2 CI runs on the s3 `rows` read): the answer is complete, so leave without the teardown.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
