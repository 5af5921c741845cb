from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class InsertRequest(_message.Message):
    __slots__ = ("table", "batch", "writer_id", "sequence", "timeout_s")
    TABLE_FIELD_NUMBER: _ClassVar[int]
    BATCH_FIELD_NUMBER: _ClassVar[int]
    WRITER_ID_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_S_FIELD_NUMBER: _ClassVar[int]
    table: str
    batch: bytes
    writer_id: str
    sequence: int
    timeout_s: float
    def __init__(self, table: _Optional[str] = ..., batch: _Optional[bytes] = ..., writer_id: _Optional[str] = ..., sequence: _Optional[int] = ..., timeout_s: _Optional[float] = ...) -> None: ...

class InsertResponse(_message.Message):
    __slots__ = ("items_inserted", "batches_dropped_as_duplicates", "acked_sequence")
    class AckedSequenceEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    ITEMS_INSERTED_FIELD_NUMBER: _ClassVar[int]
    BATCHES_DROPPED_AS_DUPLICATES_FIELD_NUMBER: _ClassVar[int]
    ACKED_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    items_inserted: int
    batches_dropped_as_duplicates: int
    acked_sequence: _containers.ScalarMap[str, int]
    def __init__(self, items_inserted: _Optional[int] = ..., batches_dropped_as_duplicates: _Optional[int] = ..., acked_sequence: _Optional[_Mapping[str, int]] = ...) -> None: ...

class SampleRequest(_message.Message):
    __slots__ = ("table", "batch_size", "num_batches", "sequence_length", "timeout_s", "batches_per_message")
    TABLE_FIELD_NUMBER: _ClassVar[int]
    BATCH_SIZE_FIELD_NUMBER: _ClassVar[int]
    NUM_BATCHES_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_LENGTH_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_S_FIELD_NUMBER: _ClassVar[int]
    BATCHES_PER_MESSAGE_FIELD_NUMBER: _ClassVar[int]
    table: str
    batch_size: int
    num_batches: int
    sequence_length: int
    timeout_s: float
    batches_per_message: int
    def __init__(self, table: _Optional[str] = ..., batch_size: _Optional[int] = ..., num_batches: _Optional[int] = ..., sequence_length: _Optional[int] = ..., timeout_s: _Optional[float] = ..., batches_per_message: _Optional[int] = ...) -> None: ...

class SampleResponse(_message.Message):
    __slots__ = ("batch", "table_inserts", "table_size", "num_batches")
    BATCH_FIELD_NUMBER: _ClassVar[int]
    TABLE_INSERTS_FIELD_NUMBER: _ClassVar[int]
    TABLE_SIZE_FIELD_NUMBER: _ClassVar[int]
    NUM_BATCHES_FIELD_NUMBER: _ClassVar[int]
    batch: bytes
    table_inserts: int
    table_size: int
    num_batches: int
    def __init__(self, batch: _Optional[bytes] = ..., table_inserts: _Optional[int] = ..., table_size: _Optional[int] = ..., num_batches: _Optional[int] = ...) -> None: ...

class UpdatePrioritiesRequest(_message.Message):
    __slots__ = ("table", "keys", "priorities")
    TABLE_FIELD_NUMBER: _ClassVar[int]
    KEYS_FIELD_NUMBER: _ClassVar[int]
    PRIORITIES_FIELD_NUMBER: _ClassVar[int]
    table: str
    keys: _containers.RepeatedScalarFieldContainer[int]
    priorities: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, table: _Optional[str] = ..., keys: _Optional[_Iterable[int]] = ..., priorities: _Optional[_Iterable[float]] = ...) -> None: ...

class UpdatePrioritiesResponse(_message.Message):
    __slots__ = ("updated",)
    UPDATED_FIELD_NUMBER: _ClassVar[int]
    updated: int
    def __init__(self, updated: _Optional[int] = ...) -> None: ...

class InfoRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class TableInfo(_message.Message):
    __slots__ = ("name", "size", "max_size", "inserts", "samples", "sampler", "remover", "rate_limiter", "signature_json", "bytes_in_memory", "rate_limiter_blocked_s", "bytes_used")
    NAME_FIELD_NUMBER: _ClassVar[int]
    SIZE_FIELD_NUMBER: _ClassVar[int]
    MAX_SIZE_FIELD_NUMBER: _ClassVar[int]
    INSERTS_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_FIELD_NUMBER: _ClassVar[int]
    SAMPLER_FIELD_NUMBER: _ClassVar[int]
    REMOVER_FIELD_NUMBER: _ClassVar[int]
    RATE_LIMITER_FIELD_NUMBER: _ClassVar[int]
    SIGNATURE_JSON_FIELD_NUMBER: _ClassVar[int]
    BYTES_IN_MEMORY_FIELD_NUMBER: _ClassVar[int]
    RATE_LIMITER_BLOCKED_S_FIELD_NUMBER: _ClassVar[int]
    BYTES_USED_FIELD_NUMBER: _ClassVar[int]
    name: str
    size: int
    max_size: int
    inserts: int
    samples: int
    sampler: str
    remover: str
    rate_limiter: str
    signature_json: str
    bytes_in_memory: int
    rate_limiter_blocked_s: float
    bytes_used: int
    def __init__(self, name: _Optional[str] = ..., size: _Optional[int] = ..., max_size: _Optional[int] = ..., inserts: _Optional[int] = ..., samples: _Optional[int] = ..., sampler: _Optional[str] = ..., remover: _Optional[str] = ..., rate_limiter: _Optional[str] = ..., signature_json: _Optional[str] = ..., bytes_in_memory: _Optional[int] = ..., rate_limiter_blocked_s: _Optional[float] = ..., bytes_used: _Optional[int] = ...) -> None: ...

class InfoResponse(_message.Message):
    __slots__ = ("tables", "uptime_s", "memory_budget_bytes", "memory_budget")
    TABLES_FIELD_NUMBER: _ClassVar[int]
    UPTIME_S_FIELD_NUMBER: _ClassVar[int]
    MEMORY_BUDGET_BYTES_FIELD_NUMBER: _ClassVar[int]
    MEMORY_BUDGET_FIELD_NUMBER: _ClassVar[int]
    tables: _containers.RepeatedCompositeFieldContainer[TableInfo]
    uptime_s: float
    memory_budget_bytes: int
    memory_budget: str
    def __init__(self, tables: _Optional[_Iterable[_Union[TableInfo, _Mapping]]] = ..., uptime_s: _Optional[float] = ..., memory_budget_bytes: _Optional[int] = ..., memory_budget: _Optional[str] = ...) -> None: ...

class CheckpointRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class CheckpointResponse(_message.Message):
    __slots__ = ("path",)
    PATH_FIELD_NUMBER: _ClassVar[int]
    path: str
    def __init__(self, path: _Optional[str] = ...) -> None: ...
