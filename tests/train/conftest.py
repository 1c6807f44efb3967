import pytest

pytest.importorskip("torch")
pytest.importorskip("sb3_contrib")

# the training tests share the policy tests' set-up: one torch thread, SB3's logs in pytest's tmp, a
# fixed torch seed per test
from policies.conftest import _sb3_logs_in_tmp, _torch_seed  # noqa: E402, F401


class _Payload:
    """Unpickling this creates the file ``marker`` (what a hostile archive's payload could do)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


@pytest.fixture
def poison():
    """``poison(archive, key, marker)``: rewrite the SB3 archive's ``data`` entry ``key`` as a pickled
    payload that creates ``marker`` when unpickled; the entry's readable JSON attributes stay."""
    import base64
    import json
    import pickle
    import zipfile

    def rewrite(archive, key, marker):
        with zipfile.ZipFile(archive) as zf:
            members = {name: zf.read(name) for name in zf.namelist()}
        data = json.loads(members["data"])
        entry = data.get(key) if isinstance(data.get(key), dict) else {":type:": "<class 'object'>"}
        entry[":serialized:"] = base64.b64encode(pickle.dumps(_Payload(marker))).decode()
        data[key] = entry
        members["data"] = json.dumps(data).encode()
        with zipfile.ZipFile(archive, "w") as zf:
            for name, blob in members.items():
                zf.writestr(name, blob)
        return archive

    return rewrite
