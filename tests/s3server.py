"""An S3 server on loopback for tests and benchmarks: moto's server mode (``moto[server]``), on a
free port of 127.0.0.1, with a bucket, and the environment a graphkit process needs to use it
(the endpoint through fsspec's FSSPEC_S3_ENDPOINT_URL, dummy credentials)."""
from __future__ import annotations

import logging
import os
import socket


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class S3Server:
    """``with S3Server() as s3: s3.env``; ``s3.make_bucket(name)``; ``s3.stop()`` ends it early."""

    def __init__(self, bucket: str = "gk-test"):
        from moto.server import ThreadedMotoServer

        logging.getLogger("werkzeug").setLevel(logging.ERROR)  # (a line per request otherwise)
        self.port = free_port()
        self.endpoint = f"http://127.0.0.1:{self.port}"
        self.bucket = bucket
        self._server = ThreadedMotoServer(ip_address="127.0.0.1", port=self.port, verbose=False)
        self._running = False

    @property
    def env(self) -> dict:
        return {"FSSPEC_S3_ENDPOINT_URL": self.endpoint, "AWS_ACCESS_KEY_ID": "testing",
                "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1",
                "AWS_CONFIG_FILE": os.devnull, "AWS_SHARED_CREDENTIALS_FILE": os.devnull}

    def client(self):
        import boto3

        return boto3.client("s3", endpoint_url=self.endpoint, region_name="us-east-1",
                            aws_access_key_id="testing", aws_secret_access_key="testing")

    def make_bucket(self, name: str) -> None:
        self.client().create_bucket(Bucket=name)

    def buckets(self) -> list[str]:
        return [b["Name"] for b in self.client().list_buckets()["Buckets"]]

    def keys(self, prefix: str = "") -> dict[str, bytes]:
        """Every object below ``prefix`` of the test bucket: key -> bytes."""
        c, out = self.client(), {}
        for page in c.get_paginator("list_objects_v2").paginate(Bucket=self.bucket, Prefix=prefix):
            for o in page.get("Contents", []):
                out[o["Key"]] = c.get_object(Bucket=self.bucket, Key=o["Key"])["Body"].read()
        return out

    def put(self, key: str, data: bytes) -> None:
        self.client().put_object(Bucket=self.bucket, Key=key, Body=data)

    def start(self) -> "S3Server":
        self._server.start()
        self._running = True
        self.make_bucket(self.bucket)
        return self

    def stop(self) -> None:
        if self._running:
            self._running = False
            self._server.stop()

    def __enter__(self) -> "S3Server":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
