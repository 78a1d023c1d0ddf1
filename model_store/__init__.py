"""racer.model_store: checkpoints and run files on S3 or a local directory, behind one interface.

``open_store(uri)`` gives an :class:`ObjectStore` (``s3://bucket/prefix`` → :class:`S3Store`, a path →
:class:`LocalStore`); :class:`RunStore` lays runs out on it (``runs/{run_id}/checkpoints/…``,
``latest.json``/``best.json`` pointers written last, run files; the whole layout is in ARCHITECTURE.md);
:func:`list_models` backs ``racer models ls``. Nothing read from the store is unpickled: metadata is JSON,
checkpoints are bytes the caller decodes.
"""

from model_store.runs import (
    POINTERS,
    RunStore,
    check_run_id,
    checkpoint_key,
    checkpoint_meta_key,
    list_models,
    pointer_key,
)
from model_store.store import (
    DEFAULT_S3_CONFIG,
    LocalStore,
    ObjectInfo,
    ObjectStore,
    S3Store,
    StoreError,
    StoreKeyError,
    StoreUnavailable,
    check_key,
    is_transient,
    local_store,
    open_store,
)

__all__ = [
    "DEFAULT_S3_CONFIG",
    "POINTERS",
    "LocalStore",
    "ObjectInfo",
    "ObjectStore",
    "RunStore",
    "S3Store",
    "StoreError",
    "StoreKeyError",
    "StoreUnavailable",
    "check_key",
    "check_run_id",
    "is_transient",
    "checkpoint_key",
    "checkpoint_meta_key",
    "list_models",
    "local_store",
    "open_store",
    "pointer_key",
]
