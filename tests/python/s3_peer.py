"""Peers of the object-store tests (tests/store.rs): pyarrow and boto3 against the moto S3 server.

  rows-s3 ENDPOINT BUCKET PREFIX   the committed pairs (manifest-listed objects), read with pyarrow's S3FileSystem
  rows-local FOLDER                the same from a dataset folder
  uploads ENDPOINT BUCKET          incomplete multipart uploads (boto3)
  objects ENDPOINT BUCKET PREFIX   every key under PREFIX with its size and ETag (boto3)
  delete ENDPOINT BUCKET KEY       deletes one object (boto3)
  abandon ENDPOINT BUCKET PREFIX RECORD OBJECT   a writer that died mid multipart upload: one part sent, record written
  keys ENDPOINT BUCKET             every key of the bucket (boto3), as a JSON list
  buckets ENDPOINT                 the bucket names (boto3), as a JSON list
  put ENDPOINT BUCKET KEY FILE     puts the bytes of the local FILE as one object (boto3)
  copy ENDPOINT BUCKET FROM TO     copies one object to another key of the bucket (boto3)

Rows are printed as JSON: {pair_key: [status, overlap_source, n_source_points, n_target_points, unit_index]}.
The endpoint's credentials are taken from the environment (AWS_ACCESS_KEY_ID, ...).
"""
import json
import os
import sys

import pyarrow.parquet as pq


def summary(table):
    cols = table.to_pydict()
    return {
        k: [s, o, len(a), len(b), u]
        for k, s, o, a, b, u in zip(
            cols["pair_key"], cols["status"], cols["overlap_source"], cols["source_points"], cols["target_points"], cols["unit_index"]
        )
    }


def s3fs(endpoint):
    from pyarrow import fs

    scheme, host = endpoint.split("://")
    return fs.S3FileSystem(
        endpoint_override=host,
        scheme=scheme,
        access_key=os.environ["AWS_ACCESS_KEY_ID"],
        secret_key=os.environ["AWS_SECRET_ACCESS_KEY"],
        region=os.environ.get("AWS_REGION", "us-east-1"),
    )


def boto(endpoint, service="s3"):
    import boto3

    return boto3.client(service, endpoint_url=endpoint, region_name=os.environ.get("AWS_REGION", "us-east-1"))


def rows_s3(endpoint, bucket, prefix):
    """As the README shows: the manifest entries name the committed objects; pyarrow.dataset reads them."""
    import pyarrow.dataset as pads
    from pyarrow import fs as pafs

    s3 = s3fs(endpoint)
    entries = [
        json.loads(s3.open_input_stream(i.path).read())
        for i in s3.get_file_info(pafs.FileSelector(f"{bucket}/{prefix}/manifest"))
        if i.base_name.startswith("pairs-")
    ]
    files = [f"{bucket}/{prefix}/shards/{e['file']}" for e in entries]
    return summary(pads.dataset(files, filesystem=s3).to_table())


def rows_local(folder):
    out = {}
    for name in sorted(os.listdir(os.path.join(folder, "manifest"))):
        if name.startswith("pairs-"):
            with open(os.path.join(folder, "manifest", name)) as f:
                entry = json.load(f)
            out.update(summary(pq.read_table(os.path.join(folder, "shards", entry["file"]))))
    return out


def main():
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "rows-s3":
        print(json.dumps(rows_s3(*args), sort_keys=True))
    elif cmd == "rows-local":
        print(json.dumps(rows_local(*args), sort_keys=True))
    elif cmd == "uploads":
        endpoint, bucket = args
        print(len(boto(endpoint).list_multipart_uploads(Bucket=bucket).get("Uploads", [])))
    elif cmd == "objects":
        endpoint, bucket, prefix = args
        listed = boto(endpoint).list_objects_v2(Bucket=bucket, Prefix=prefix + "/").get("Contents", [])
        print(json.dumps({o["Key"][len(prefix) + 1 :]: [o["Size"], o["ETag"].strip('"')] for o in listed}))
    elif cmd == "delete":
        endpoint, bucket, key = args
        boto(endpoint).delete_object(Bucket=bucket, Key=key)
    elif cmd == "abandon":
        endpoint, bucket, prefix, record, obj = args
        s3 = boto(endpoint)
        key = f"{prefix}/shards/{obj}"
        upload = s3.create_multipart_upload(Bucket=bucket, Key=key)["UploadId"]
        s3.upload_part(Bucket=bucket, Key=key, UploadId=upload, PartNumber=1, Body=b"x" * (5 << 20))
        body = json.dumps({"object": obj, "upload_id": upload}).encode()
        s3.put_object(Bucket=bucket, Key=f"{prefix}/.tmp/{record}", Body=body)
        print(upload)
    elif cmd == "keys":
        endpoint, bucket = args
        pages = boto(endpoint).get_paginator("list_objects_v2").paginate(Bucket=bucket)
        print(json.dumps(sorted(o["Key"] for p in pages for o in p.get("Contents", []))))
    elif cmd == "buckets":
        (endpoint,) = args
        print(json.dumps(sorted(b["Name"] for b in boto(endpoint).list_buckets().get("Buckets", []))))
    elif cmd == "put":
        endpoint, bucket, key, path = args
        with open(path, "rb") as f:
            boto(endpoint).put_object(Bucket=bucket, Key=key, Body=f.read())
    elif cmd == "copy":
        endpoint, bucket, src, dst = args
        boto(endpoint).copy_object(Bucket=bucket, Key=dst, CopySource={"Bucket": bucket, "Key": src})
    else:
        sys.exit(f"unknown command {cmd}")


if __name__ == "__main__":
    main()
