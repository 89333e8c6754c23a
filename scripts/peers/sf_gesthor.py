"""Sample Factory 2 (APPO, its shared-memory rollout and inference workers) on GesTHOR: a peer
of the farm for docs/bench/peers.md. Trains on CPU, then evaluates SR at the first stop on the
val programs `orchestrator eval --max-programs` picks, sampling from the policy as `orchestrator
eval` does without --greedy.

Each Sample Factory env is one GesTHOR env (a native pool of one, scripts/peers/common.py's
PoolVec: Sample Factory pins gymnasium < 1.0, `gesthor.make_vec` needs 1.x); Sample Factory's
worker processes do the vectorisation: 4 workers x 8 envs, as the default's 4 workers x 8.

Settings follow configs/tiny/both.toml where Sample Factory has them: rollout 128 and full BPTT
over it, a batch of 4,096 (32 x 128) learned in 2 minibatches for 4 epochs, Adam 3e-4 (constant:
Sample Factory 2.1 has no linear decay), clip 0.2 (policy and value), gamma 0.99, GAE lambda 0.99,
grad norm 0.5, value 0.5, entropy 0.01, GRU 256. APPO stays asynchronous: acting runs ahead of
learning.

The network is the default's (scripts/peers/net.py; layer sizes and activations as
learner/src/net, PyTorch's initialisation). The frozen pretrained RGB-D encoder of the config's
model.encoder_weights runs in the env, in the rollout worker, under no_grad, one frame at a time:
its 64x8x8 features are the observation Sample Factory stores, so its learner trains only the
layers above (never re-running the encoder). Its encoder slot holds net.Above (features ─ 1x1
conv 64→16 ─ FC 256; the gesture's flat_and_turned reading with the person's pose; target
embedding 256; pose FC 256), its core the GRU 1x256, and its actor-critic (GesthorActorCritic)
the default's separate actor 256-256-4 and critic 256-256-1 MLPs in place of Sample Factory's
shared decoder. The pose, target and gesture mask come from the pool's records
(common.policy_inputs), as the default reads them.

Frames: every pool step is one Sample Factory step, the step that starts an episode included
(GesthorEnv): its env steps count what the default's frames count, and that step stays out of
the loss (Sample Factory's invalid samples; it lowers each minibatch's learning rate by their
share). What differs from the default, beyond Sample Factory's own algorithm (asynchronous
APPO, constant learning rate): a truncated episode bootstraps 0 where the default bootstraps
the value of its final observation, and the initial weights.

Usage: sf_gesthor.py train --train_dir DIR --experiment NAME --train_for_env_steps N [SF flags]
       sf_gesthor.py eval --train_dir DIR --experiment NAME --eval_programs 500 --out results.json
"""

import json
import os
import sys
import time

import gymnasium as gym
import numpy as np
import torch
from torch import nn

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import SEED, PoolVec, evaluate, val_programs  # noqa: E402

from sample_factory.algo.learning.learner import Learner  # noqa: E402
from sample_factory.algo.utils.context import global_model_factory  # noqa: E402
from sample_factory.algo.utils.rl_utils import prepare_and_normalize_obs  # noqa: E402
from sample_factory.cfg.arguments import load_from_checkpoint, parse_full_cfg, parse_sf_args  # noqa: E402
from sample_factory.envs.env_utils import register_env  # noqa: E402
from sample_factory.algo.utils.tensor_dict import TensorDict  # noqa: E402
from sample_factory.model.actor_critic import ActorCriticSharedWeights, create_actor_critic  # noqa: E402
from sample_factory.model.encoder import Encoder  # noqa: E402
from sample_factory.train import run_rl  # noqa: E402

import net  # noqa: E402
from common import GestureIds, encoder_weights, policy_inputs  # noqa: E402

ENV_NAME = "gesthor_both"
_ENCODERS = {}


def frozen_encoder(cfg):
    """One frozen encoder per process (the rollout workers' envs share it)."""
    path = cfg.gesthor_encoder_weights or encoder_weights(cfg.gesthor_config)
    if path not in _ENCODERS:
        _ENCODERS[path] = net.load_encoder(path)
    return _ENCODERS[path]


def stored_inputs(vec, encoder, ids):
    """A PoolVec's current step → Sample Factory's observation, the default's stored form: the
    frozen encoder's features, the masked gesture, its id [env, change count], target and pose."""
    p = policy_inputs(vec)
    n = len(p["target"])
    return {
        "visual": net.encoder_features(encoder, p["rgb"], p["depth"]).numpy(),
        "gesture": p["gesture"].astype(np.float32),
        "gesture_id": np.stack([ids.base, ids(p["gesture"]) >> 20], 1).astype(np.float32),
        "target": p["target"].astype(np.float32).reshape(n, 1),
        "pose": p["pose"],
    }


def sf_observation_space():
    return gym.spaces.Dict(
        {
            "visual": gym.spaces.Box(-np.inf, np.inf, (64, 8, 8), np.float32),
            "gesture": gym.spaces.Box(-1.0, 1.0, (100, 95), np.float32),
            "gesture_id": gym.spaces.Box(0, np.inf, (2,), np.float32),
            "target": gym.spaces.Box(0, net.TARGET_CATEGORIES - 1, (1,), np.float32),
            "pose": gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
        }
    )


class GesthorEnv(gym.Env):
    """One GesTHOR env for Sample Factory, every pool step one Sample Factory step (so its count
    of env steps is the default's frames): an episode's final observation comes with done unset
    and `is_active` False, so Sample Factory repeats the last action without asking the policy
    and marks that step invalid (out of the loss, as the default masks it); the pool's step then
    ignores the action and starts the next episode, reported as done, and the reset that Sample
    Factory makes after it returns that first observation without stepping."""

    def __init__(self, cfg, env_config, render_mode=None):
        torch.set_num_threads(1)  # the frozen encoder, one frame at a time, in a rollout worker
        worker = env_config.worker_index if env_config else 0
        index = env_config.vector_index if env_config else 0
        # every env its own stream of programs
        seed = cfg.seed * 100_003 + worker * 1_000 + index if cfg.seed is not None else SEED + 1_000 * worker + index
        self.vec = PoolVec("train", 1, cfg.gesthor_config, cfg.gesthor_dataset, seed, method=cfg.gesthor_method)
        self.encoder = frozen_encoder(cfg)
        self.ids = GestureIds(1, base=worker * cfg.num_envs_per_worker + index)
        self.observation_space = sf_observation_space()
        self.action_space = gym.spaces.Discrete(4)
        self.render_mode = render_mode
        self._started = False
        self._summary = None  # the ended episode's, until its done is reported

    def _obs(self):
        return {k: v[0] for k, v in stored_inputs(self.vec, self.encoder, self.ids).items()}

    def reset(self, seed=None, options=None):
        if not self._started:
            self._started = True
            self.vec.reset()
        # else: the step that reported done started the next episode already
        return self._obs(), {}

    def step(self, action):
        _, reward, term, trunc, _ = self.vec.step(np.array([int(action)]))
        if self._summary is not None:  # the action was ignored: this step started an episode
            s, self._summary = self._summary, None
            out = {
                "episode_extra_stats": {
                    "success": float(s["success"] != 0),
                    "success_first_stop": float(s["success"] != 0 and s["num_stops"] == 1),
                }
            }
            return self._obs(), float(reward[0]), s["terminated"], s["truncated"], out
        if term[0] or trunc[0]:
            r = self.vec._records[0]
            self._summary = {
                "success": int(r["summary"]["success"]),
                "num_stops": int(r["summary"]["num_stops"]),
                "terminated": bool(term[0]),
                "truncated": bool(trunc[0]),
            }
            return self._obs(), float(reward[0]), False, False, {"is_active": False}
        return self._obs(), float(reward[0]), False, False, {}

    def render(self):
        return None


def make_gesthor_env(full_env_name, cfg=None, env_config=None, render_mode=None):
    return GesthorEnv(cfg, env_config, render_mode)


class GesthorEncoder(Encoder):
    """Sample Factory's encoder slot: the default's layers below the GRU (net.Above) on the
    stored features, gesture, target and pose."""

    def __init__(self, cfg, obs_space):
        super().__init__(cfg)
        self.above = net.Above(cfg.gesthor_hidden)

    def forward(self, obs):
        ids = obs["gesture_id"].long()
        # an invalid step's slot (an episode's final observation, not written: is_active) holds
        # Sample Factory's fill value or an older observation: its target is kept a category
        target = obs["target"].long().view(-1).clamp(0, net.TARGET_CATEGORIES - 1)
        return self.above(obs["visual"], obs["gesture"], target, obs["pose"], (ids[:, 0] << 32) | ids[:, 1])

    def get_out_size(self):
        return self.above.out_size


def make_gesthor_encoder(cfg, obs_space):
    return GesthorEncoder(cfg, obs_space)


class GesthorActorCritic(ActorCriticSharedWeights):
    """Encoder, GRU (Sample Factory's core), then the default's separate actor and critic MLPs
    (256-256-4, 256-256-1) in place of Sample Factory's shared decoder (left empty)."""

    def __init__(self, model_factory, obs_space, action_space, cfg):
        super().__init__(model_factory, obs_space, action_space, cfg)
        heads = net.Heads(cfg.gesthor_hidden, action_space.n)
        self.actor_mlp, self.critic_mlp = heads.actor[:-1], heads.critic[:-1]
        # Sample Factory's output layers take the MLPs' last layers' place (same sizes)
        self.action_parameterization.distribution_linear = heads.actor[-1]
        self.critic_linear = heads.critic[-1]

    def forward_tail(self, core_output, values_only, sample_actions):
        values = self.critic_linear(self.critic_mlp(core_output)).squeeze()
        result = TensorDict(values=values)
        if values_only:
            return result
        params, self.last_action_distribution = self.action_parameterization(self.actor_mlp(core_output))
        result["action_logits"] = params
        self._maybe_sample_actions(sample_actions, result)
        return result


def make_actor_critic(cfg, obs_space, action_space):
    return GesthorActorCritic(global_model_factory(), obs_space, action_space, cfg)


def register():
    register_env(ENV_NAME, make_gesthor_env)
    global_model_factory().register_encoder_factory(make_gesthor_encoder)
    global_model_factory().register_actor_critic_factory(make_actor_critic)


def add_args(parser, evaluation):
    p = parser
    p.add_argument("--gesthor_config", default="configs/tiny/both.toml")
    p.add_argument("--gesthor_dataset", default="data/gond")
    p.add_argument("--gesthor_method", default="both")
    p.add_argument("--gesthor_hidden", default=256, type=int)
    p.add_argument("--gesthor_encoder_weights", default=None, help="the frozen encoder (default: the config's)")
    if evaluation:
        p.add_argument("--eval_programs", default=500, type=int)
        p.add_argument("--eval_envs", default=32, type=int)
        p.add_argument("--out", default=None)
    # configs/tiny/both.toml's [ppo], farm/src/config.rs's defaults where it is silent
    p.set_defaults(
        env=ENV_NAME,
        algo="APPO",
        device="cpu",
        num_workers=4,
        num_envs_per_worker=8,
        worker_num_splits=2,  # double-buffered sampling: half of a worker's envs step while the other half waits
        rollout=128,
        recurrence=128,
        batch_size=2048,
        num_batches_per_epoch=2,
        num_epochs=4,
        learning_rate=3e-4,
        ppo_clip_ratio=0.2,
        ppo_clip_value=0.2,
        gamma=0.99,
        gae_lambda=0.99,
        max_grad_norm=0.5,
        value_loss_coeff=0.5,
        exploration_loss_coeff=0.01,
        normalize_input=False,
        normalize_returns=False,
        reward_scale=1.0,
        use_rnn=True,
        rnn_type="gru",
        rnn_size=256,
        rnn_num_layers=1,
        decoder_mlp_layers=[],  # the actor's and critic's own MLPs: GesthorActorCritic
        nonlinearity="relu",
        actor_critic_share_weights=True,
        adam_eps=1e-5,
        env_frameskip=1,
        seed=SEED,
        with_wandb=False,
        save_every_sec=60,
        keep_checkpoints=2,
        experiment_summaries_interval=10,
        serial_mode=False,
        async_rl=True,
        decorrelate_envs_on_one_worker=False,  # its warm-up random steps would be frames the others do not spend
        set_workers_cpu_affinity=False,
    )


def parse(argv, evaluation):
    if not any(a.startswith("--env") for a in argv):
        argv = [f"--env={ENV_NAME}", *argv]
    parser, _ = parse_sf_args(argv=argv, evaluation=evaluation)
    add_args(parser, evaluation)
    return parse_full_cfg(parser, argv)


def train(argv):
    cfg = parse(argv, evaluation=False)
    torch.set_num_threads(1)  # the learner's threads; the rollout and inference workers take the other core
    t0 = time.time()
    status = run_rl(cfg)
    print(json.dumps({"sf_train_seconds": time.time() - t0, "status": int(status)}), flush=True)
    return status


def evaluate_checkpoint(argv):
    cfg = load_from_checkpoint(parse(argv, evaluation=True))
    torch.set_num_threads(2)
    space = sf_observation_space()
    actor_critic = create_actor_critic(cfg, space, gym.spaces.Discrete(4))
    actor_critic.eval()
    actor_critic.model_to_device(torch.device("cpu"))
    checkpoints = Learner.get_checkpoints(Learner.checkpoint_dir(cfg, 0), "checkpoint_*")
    # the newest, as Learner.load_checkpoint takes it; our own file, so not weights_only (torch 2.6+
    # refuses the numpy scalars Sample Factory pickles into it)
    state = torch.load(checkpoints[-1], map_location="cpu", weights_only=False)
    actor_critic.load_state_dict(state["model"])

    programs = val_programs(cfg.gesthor_dataset, cfg.eval_programs)
    vec = PoolVec(
        "val", cfg.eval_envs, cfg.gesthor_config, cfg.gesthor_dataset, SEED, method=cfg.gesthor_method, programs=programs
    )
    rnn = torch.zeros(cfg.eval_envs, cfg.rnn_size)
    encoder = frozen_encoder(cfg)
    ids = GestureIds(cfg.eval_envs)

    def act(obs, first):
        # reads the vector's buffers: the step `obs` came from
        nonlocal rnn
        rnn[torch.from_numpy(first)] = 0.0
        with torch.no_grad():
            x = {k: torch.from_numpy(v) for k, v in stored_inputs(vec, encoder, ids).items()}
            x = prepare_and_normalize_obs(actor_critic, x)
            out = actor_critic(x, rnn)  # samples its actions, as in training
        rnn = out["new_rnn_states"]
        return out["actions"].view(-1).numpy()

    ev = evaluate(vec, act, programs, finished=vec.finished)
    ev["checkpoint"] = checkpoints[-1] if checkpoints else None
    ev["env_steps"] = int(state.get("env_steps", 0))
    print(json.dumps(ev), flush=True)
    if cfg.out:
        with open(cfg.out, "w") as f:
            json.dump(ev, f, indent=1)


def main():
    register()
    if len(sys.argv) < 2 or sys.argv[1] not in ("train", "eval"):
        print(__doc__)
        return 2
    argv = sys.argv[2:]
    return train(argv) if sys.argv[1] == "train" else evaluate_checkpoint(argv)


if __name__ == "__main__":
    sys.exit(main())
