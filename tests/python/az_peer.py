"""Peers of the Azure tests (tests/azure.rs): azure-storage-blob and pyarrow against a local Azurite.

  create-container ENDPOINT CONTAINER         creates a container
  objects ENDPOINT CONTAINER PREFIX           every committed blob under PREFIX with its size and ETag
  uncommitted ENDPOINT CONTAINER              blobs that hold only uncommitted blocks (a block upload never finished)
  blocks ENDPOINT CONTAINER NAME              the number of committed blocks of one blob
  rows-az ENDPOINT CONTAINER PREFIX           the committed pairs (manifest-listed blobs), read with pyarrow
  delete ENDPOINT CONTAINER NAME              deletes one blob
  put ENDPOINT CONTAINER NAME TEXT            writes one blob (overwrites)
  corrupt ENDPOINT CONTAINER NAME             flips one byte of a blob (same size)
  abandon ENDPOINT CONTAINER PREFIX RECORD OBJECT   a writer that died mid block upload: one block staged, record written
  copy ENDPOINT CONTAINER FROM TO             copies one blob to another name of the container
  names ENDPOINT CONTAINER                    every blob name of the container, uncommitted block uploads included
  containers ENDPOINT                         the container names

ENDPOINT is Azurite's blob endpoint, http://127.0.0.1:<port>; the account is Azurite's well-known
devstoreaccount1 with its published key (the same object_store's emulator mode uses). Rows are printed as
in s3_peer.py: {pair_key: [status, overlap_source, n_source_points, n_target_points, unit_index]}.
"""
import base64
import io
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

# Azurite's well-known development account (public, documented; not a secret).
ACCOUNT = "devstoreaccount1"
KEY = "Eby8vdM02xNOcqFlqUwJPLlmEtlCDXJ1OUzFT50uSRZ6IFsuFq2UVErCz4I6tq/K1SZFPTOtr/KBHBeksoGMGw=="


def service(endpoint):
    from azure.storage.blob import BlobServiceClient

    conn = f"DefaultEndpointsProtocol=http;AccountName={ACCOUNT};AccountKey={KEY};BlobEndpoint={endpoint}/{ACCOUNT};"
    return BlobServiceClient.from_connection_string(conn)


def container(endpoint, name):
    return service(endpoint).get_container_client(name)


def rows_az(endpoint, name, prefix):
    """As a reader would: the manifest entries name the committed blobs; pyarrow reads them."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from s3_peer import summary

    c = container(endpoint, name)
    entries = [
        json.loads(c.download_blob(b.name).readall())
        for b in c.list_blobs(name_starts_with=f"{prefix}/manifest/")
        if b.name.rsplit("/", 1)[-1].startswith("pairs-")
    ]
    tables = [pq.read_table(io.BytesIO(c.download_blob(f"{prefix}/shards/{e['file']}").readall())) for e in entries]
    return summary(pa.concat_tables(tables)) if tables else {}


def main():
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "create-container":
        endpoint, name = args
        service(endpoint).create_container(name)
    elif cmd == "objects":
        endpoint, name, prefix = args
        listed = container(endpoint, name).list_blobs(name_starts_with=prefix + "/")
        print(json.dumps({b.name[len(prefix) + 1 :]: [b.size, b.etag.strip('"')] for b in listed}))
    elif cmd == "uncommitted":
        endpoint, name = args
        c = container(endpoint, name)
        committed = {b.name for b in c.list_blobs()}
        everything = {b.name for b in c.list_blobs(include=["uncommittedblobs"])}
        print(json.dumps(sorted(everything - committed)))
    elif cmd == "blocks":
        endpoint, name, blob = args
        committed, _ = container(endpoint, name).get_blob_client(blob).get_block_list("committed")
        print(len(committed))
    elif cmd == "rows-az":
        print(json.dumps(rows_az(*args), sort_keys=True))
    elif cmd == "delete":
        endpoint, name, blob = args
        container(endpoint, name).delete_blob(blob)
    elif cmd == "put":
        endpoint, name, blob, text = args
        container(endpoint, name).upload_blob(blob, text.encode(), overwrite=True)
    elif cmd == "corrupt":
        # One byte flipped in the middle: the same size, another content (only a hash can tell).
        endpoint, name, blob = args
        c = container(endpoint, name)
        data = bytearray(c.download_blob(blob).readall())
        data[len(data) // 2] ^= 0xFF
        c.upload_blob(blob, bytes(data), overwrite=True)
    elif cmd == "abandon":
        endpoint, name, prefix, record, obj = args
        c = container(endpoint, name)
        c.get_blob_client(f"{prefix}/shards/{obj}").stage_block(base64.b64encode(b"%032x" % 1).decode(), b"x" * (1 << 20))
        # object_store's Azure client has no upload id (blocks belong to the blob name): it records "".
        body = json.dumps({"object": obj, "upload_id": ""}).encode()
        c.upload_blob(f"{prefix}/.tmp/{record}", body, overwrite=True)
    elif cmd == "copy":
        endpoint, name, source, target = args
        c = container(endpoint, name)
        c.upload_blob(target, c.download_blob(source).readall(), overwrite=True)
    elif cmd == "names":
        endpoint, name = args
        print(json.dumps(sorted(b.name for b in container(endpoint, name).list_blobs(include=["uncommittedblobs"]))))
    elif cmd == "containers":
        (endpoint,) = args
        print(json.dumps(sorted(c.name for c in service(endpoint).list_containers())))
    else:
        sys.exit(f"unknown command {cmd}")


if __name__ == "__main__":
    main()
