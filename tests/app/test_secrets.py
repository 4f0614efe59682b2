"""API keys never reach the run directory or the console.

A real training process (``python -m torchrl_ahrs.train``, as a user runs it) talks to a local
OpenAI-compatible server with one fake key in ``$OPENAI_API_KEY`` and another in ``llm.api_key``; the
server's first answer quotes the key back (as OpenAI's HTTP 401 does). Afterwards neither key may
appear in any byte of any file under the run directory (config.yaml, .hydra/, metrics CSV and
TensorBoard files, checkpoint.pt, llm_calls.jsonl, scheduler_decisions.jsonl, train.log) nor in the
process's stdout/stderr.
"""

import json
import os
import subprocess
import sys
import uuid

import pytest
from conftest import make_cfg

from torchrl_ahrs.app.shared.redaction import RedactHydraOutput, is_secret_key, secret_values
from torchrl_ahrs.app.shared.run_dir import LLM_CALLS
from torchrl_ahrs.llm.client import LLMClient, LLMConfig


def fake_key(label):
    return f"sk-test-{label}-{uuid.uuid4().hex}"  # unique: cannot match anything by accident


def files_containing(folder, secrets):
    """(relative path, secret) for every file under ``folder`` whose bytes contain a secret."""
    hits = []
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            data = path.read_bytes()
            hits += [(str(path.relative_to(folder)), secret) for secret in secrets if secret.encode() in data]
    return hits


@pytest.mark.slow
def test_keys_from_environment_and_config_never_reach_run_dir_or_console(llm_server, tmp_path):
    env_key, config_key = fake_key("env"), fake_key("config")
    llm_server.script = [("echo_key", 401), ("ok", "~[4]~")]  # the 401 quotes the key; not retried
    run_dir = tmp_path / "run"
    command = [
        sys.executable,
        "-m",
        "torchrl_ahrs.train",
        "task=point_reach",
        "method=ahrs_wo_a",
        "llm=openai",
        "llm.model=openai/test-model",
        f"llm.api_base={llm_server.api_base}",
        f"llm.api_key={config_key}",
        "llm.cache_dir=null",
        "llm.timeout=5",
        "llm.max_retries=1",
        "llm.backoff=0",
        "scheduler.interval=1",
        "task.max_episode_steps=20",
        "trainer.total_frames=2048",
        "trainer.num_envs=32",
        "trainer.frames_per_batch=1024",
        "trainer.mini_batch_size=256",
        "trainer.num_epochs=1",
        "trainer.progress_bar=false",
        "model.hidden_sizes=[32,32]",
        "checkpoint.interval=1",
        f"hydra.run.dir={run_dir}",
    ]
    environment = dict(os.environ, OPENAI_API_KEY=env_key, PYTHONUNBUFFERED="1")
    done = subprocess.run(command, env=environment, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]

    # the run really used the key and really wrote every kind of file (else the scan below proves nothing)
    assert [request["auth"] for request in llm_server.requests] == [f"Bearer {config_key}"] * 2
    for name in ("config.yaml", ".hydra/config.yaml", ".hydra/overrides.yaml", ".hydra/hydra.yaml", "checkpoint.pt"):
        assert (run_dir / name).is_file(), name
    assert list((run_dir / "metrics" / "scalars").glob("*.csv")) and list(run_dir.rglob("events.out.tfevents*"))
    calls = [json.loads(line) for line in (run_dir / LLM_CALLS).read_text().splitlines()]
    assert "Incorrect API key provided: ***" in calls[0]["error"]  # the echoed key, masked
    decisions = (run_dir / "scheduler_decisions.jsonl").read_text()
    assert "AuthenticationError" in decisions and calls[-1]["parsed"] == 4

    assert files_containing(run_dir, [env_key, config_key]) == []
    for stream in (done.stdout, done.stderr):
        assert env_key not in stream and config_key not in stream
    overrides = (run_dir / ".hydra" / "overrides.yaml").read_text()
    assert "llm.api_key=<redacted>" in overrides and "trainer.total_frames=2048" in overrides  # nothing else lost


def test_environment_key_is_sent_and_masked_in_the_call_log(llm_server, tmp_path, monkeypatch):
    env_key = fake_key("env")
    monkeypatch.setenv("TEST_SECRETS_KEY", env_key)
    llm_server.script = [("echo_key", 401)]
    config = LLMConfig(model="openai/m", api_base=llm_server.api_base, api_key_env="TEST_SECRETS_KEY", timeout=5)
    reply = LLMClient(config, calls_path=tmp_path / LLM_CALLS, sleep=lambda seconds: None).complete(
        [{"role": "user", "content": "x"}], "t"
    )
    assert llm_server.requests[0]["auth"] == f"Bearer {env_key}"
    assert reply.text is None and reply.attempts == 1 and "Incorrect API key provided: ***" in reply.error
    assert env_key not in (tmp_path / LLM_CALLS).read_text()
    assert env_key not in repr(config) and "sk-" not in repr(LLMConfig(model="m", api_key="sk-abcdef"))


def test_hydra_output_is_registered_for_redaction():
    cfg = make_cfg(hydra=True)
    targets = [callback.get("_target_") for callback in (cfg.hydra.callbacks or {}).values()]
    assert "torchrl_ahrs.app.shared.redaction.RedactHydraOutput" in targets, (
        "conf/config.yaml must register hydra.callbacks.redact_secrets._target_: "
        "torchrl_ahrs.app.shared.redaction.RedactHydraOutput, or .hydra/ keeps llm.api_key=... verbatim"
    )
    assert RedactHydraOutput  # importable by Hydra's instantiate


@pytest.mark.parametrize(
    "name, secret",
    [("llm.api_key", True), ("+llm.api_key", True), ("wandb_token", True), ("db.password", True)]
    + [("llm.api_key_env", False), ("llm.max_tokens", False), ("trainer.total_frames", False)],
)
def test_secret_field_names(name, secret):
    assert is_secret_key(name) is secret


def test_secret_values_come_from_config_and_overrides():
    config = {"llm": {"api_key": "sk-from-yaml", "api_key_env": "OPENAI_API_KEY", "max_tokens": 1024}}
    assert secret_values(config, ["+logger.token='tok-123456'", "seed=1"]) == {"sk-from-yaml", "tok-123456"}


def test_callback_rewrites_job_and_sweep_files(tmp_path):
    key = fake_key("config")
    overrides = ["llm=openai", f"llm.api_key={key}", f"hydra.run.dir={tmp_path}", f"hydra.sweep.dir={tmp_path}"]
    cfg = make_cfg(*overrides, hydra=True)
    cfg.hydra.runtime.output_dir = str(tmp_path)
    (tmp_path / ".hydra").mkdir()
    for name in ("config.yaml", "hydra.yaml", "overrides.yaml"):
        (tmp_path / ".hydra" / name).write_text(f"- llm.api_key={key}\n- llm.max_tokens=1024\n")
    (tmp_path / "multirun.yaml").write_text(f"api_key: {key}\n")
    callback = RedactHydraOutput()
    callback.on_job_start(config=cfg, task_function=None)
    callback.on_multirun_end(config=cfg)
    assert files_containing(tmp_path, [key]) == []
    assert (tmp_path / ".hydra" / "overrides.yaml").read_text() == "- llm.api_key=<redacted>\n- llm.max_tokens=1024\n"


def test_an_answer_echoing_the_key_is_masked_and_a_huge_answer_is_capped(llm_server, tmp_path, monkeypatch):
    env_key = fake_key("echo")
    monkeypatch.setenv("TEST_SECRETS_KEY", env_key)
    llm_server.script = [("ok", f"your key is {env_key} ~[3]~" + "x" * 200_000)]
    config = LLMConfig(model="openai/m", api_base=llm_server.api_base, api_key_env="TEST_SECRETS_KEY", timeout=5)
    reply = LLMClient(config, calls_path=tmp_path / LLM_CALLS, sleep=lambda seconds: None).complete(
        [{"role": "user", "content": "x"}], "t"
    )
    assert reply.text is not None and env_key not in reply.text and "your key is *** ~[3]~" in reply.text
    logged = (tmp_path / LLM_CALLS).read_text()
    assert env_key not in logged and len(logged) < 100_000  # capped at LOGGED_ANSWER_CHARS


def test_redact_replaces_config_and_environment_secrets(monkeypatch):
    from omegaconf import OmegaConf

    from torchrl_ahrs.train import redact

    env_key, config_key = fake_key("env"), fake_key("config")
    monkeypatch.setenv("SOME_SERVICE_TOKEN", env_key)
    text = redact(
        f"Error executing job with overrides: ['llm.api_key={config_key}'] {env_key}",
        OmegaConf.create({"llm": {"api_key": config_key}}),
    )
    assert config_key not in text and env_key not in text and "llm.api_key=<redacted>" in text


@pytest.mark.slow
def test_hydra_messages_and_a_stopped_run_print_no_key(tmp_path):
    key = fake_key("cli")
    late = tmp_path / "late.py"
    late.write_text(
        "import torch\ncalls = [0]\n\ndef compute_aux_reward(obs):\n    calls[0] = calls[0] + 1\n"
        "    if calls[0] > 40:\n        return obs['no such key']\n    return obs['reward.total'] * 0.0\n"
    )
    common = [
        sys.executable,
        "-m",
        "torchrl_ahrs.train",
        "task=point_reach",
        "trainer.total_frames=2048",
        "trainer.num_envs=16",
        "trainer.frames_per_batch=512",
        "trainer.mini_batch_size=128",
        "trainer.num_epochs=1",
        "trainer.progress_bar=false",
        "method=hdppo_a",
        f"aux.path={late}",
    ]
    # llm=offline has no api_key: Hydra's own composition error quotes the override
    refused = subprocess.run(
        [*common, f"llm.api_key={key}", f"hydra.run.dir={tmp_path / 'a'}"], capture_output=True, text=True, timeout=300
    )
    assert refused.returncode != 0 and "llm.api_key=<redacted>" in refused.stderr
    stopped = subprocess.run(
        [*common, "llm=openai", f"llm.api_key={key}", f"hydra.run.dir={tmp_path / 'b'}"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert stopped.returncode == 2 and (tmp_path / "b" / "checkpoint.pt").is_file()
    assert "KeyError: 'no such key'" in stopped.stderr and "Error executing job" not in stopped.stderr
    for done in (refused, stopped):
        assert key not in done.stdout and key not in done.stderr
