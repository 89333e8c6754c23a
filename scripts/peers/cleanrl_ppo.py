"""CleanRL-style PPO (the shape of CleanRL's ppo_atari_lstm.py, with a GRU) on GesTHOR's own
Gymnasium vector env, `gesthor.make_vec`: a peer of the farm for docs/bench/peers.md.

Settings follow configs/tiny/both.toml ([ppo] is read from it): 32 envs (the default's 4
workers x 8), rollout 128, 4 epochs of 2 minibatches of whole envs, Adam 3e-4 decayed linearly
to 0, clip 0.2 (policy and value), gamma 0.99, GAE lambda 0.99, grad norm 0.5, value 0.5,
entropy 0.01 (farm/src/config.rs's defaults), +Both at 64x64.

The network is the default's (scripts/peers/net.py; layer sizes and activations as
learner/src/net, PyTorch's initialisation): the frozen pretrained RGB-D encoder of the config's
model.encoder_weights, run under no_grad when acting, its 64x8x8 features stored in the rollout,
so PPO trains only the layers above it:
    features ─ 1x1 conv 64→16 ─ FC 256 ──────────────────────────────────┐
    gesture (zeroed where none is shown) ─ flat_and_turned ─ 256 ─────────┤ concat ─ GRU 1x256
    target category ─ embedding 37→256 ───────────────────────────────────┤   ├ actor  256-256-4
    person pose (records' person_rel: right, forward, yaw/360) ─ FC 256 ──┘   └ critic 256-256-1
The pose, target and gesture mask come from make_vec's own records (common.policy_inputs), as
the default reads them. What differs from the default's network: the initial weights, and how
the GRU runs over a minibatch (here one call per stretch of steps in which no env of the
minibatch starts an episode; the default packs each env's own stretches into one call): the
same function.

Episodes follow the farm's protocol (Gymnasium's NEXT_STEP autoreset): the step after an
episode's final observation ignores its action, so that transition is masked out of the loss,
and a truncated episode bootstraps from the value of its final observation. Its frames count
every step of every env, the masked one included, as the default's counter does (rollout x envs
per update).

Run from the repository root with the gesthor package on PYTHONPATH (scripts/peers.sh does).
"""

import argparse
import dataclasses
import json
import os
import random
import sys
import time
import tomllib
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.optim as optim
from torch.distributions.categorical import Categorical

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gesthor  # noqa: E402
import net  # noqa: E402
from common import SEED, GestureIds, evaluate, policy_inputs, val_programs  # noqa: E402


@dataclass
class Args:
    exp_name: str = "cleanrl_ppo"
    seed: int = SEED
    torch_threads: int = 2
    """the machine's cores: acting and learning take turns on them"""
    config: str = "configs/tiny/both.toml"
    encoder_weights: str = ""
    """the frozen encoder ('': the config's model.encoder_weights)"""
    dataset: str = "data/gond"
    method: str = "both"
    out: str = "runs/peers/cleanrl"
    """where the model, the log of updates and results.json go"""

    total_timesteps: int = 1_000_000
    num_envs: int = 32
    num_steps: int = 0
    """rollout length (0: the config's ppo.rollout)"""
    learning_rate: float = 0.0
    """0: the config's ppo.lr"""
    anneal_lr: bool = True
    gamma: float = 0.0
    gae_lambda: float = 0.0
    num_minibatches: int = 0
    update_epochs: int = 0
    norm_adv: bool = True
    clip_coef: float = 0.0
    clip_vloss: bool = True
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.0
    hidden: int = 256

    eval_programs: int = 500
    """SR at the first stop on this many val programs (as `orchestrator eval --max-programs`)"""
    eval_envs: int = 32


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for f in dataclasses.fields(Args):
        if f.type is bool:
            p.add_argument(f"--{f.name}", type=lambda s: s.lower() in ("1", "true", "yes"), default=f.default)
        else:
            p.add_argument(f"--{f.name}", type=f.type, default=f.default)
    args = Args(**vars(p.parse_args()))
    # zeros take the config's [ppo] (farm/src/config.rs's defaults where it is silent)
    with open(args.config, "rb") as f:
        ppo = tomllib.load(f).get("ppo", {})
    for name, key, default in (
        ("num_steps", "rollout", 128),
        ("learning_rate", "lr", 3e-4),
        ("gamma", "gamma", 0.99),
        ("gae_lambda", "gae_lambda", 0.99),
        ("num_minibatches", "minibatches", 1),
        ("update_epochs", "epochs", 4),
        ("clip_coef", "clip", 0.2),
        ("max_grad_norm", "max_grad_norm", 0.5),
    ):
        if not getattr(args, name):
            setattr(args, name, type(default)(ppo.get(key, default)))
    if not args.encoder_weights:
        with open(args.config, "rb") as f:
            args.encoder_weights = tomllib.load(f)["model"]["encoder_weights"]
    return args


class Agent(nn.Module):
    """The default's trained layers (net.Above, GRU 1x256, net.Heads) on stored inputs."""

    def __init__(self, hidden):
        super().__init__()
        self.above = net.Above(hidden)
        self.gru = nn.GRU(self.above.out_size, hidden)
        for name, param in self.gru.named_parameters():
            if "bias" in name:
                nn.init.constant_(param, 0)
            elif "weight" in name:
                nn.init.orthogonal_(param, 1.0)
        heads = net.Heads(hidden)
        self.actor, self.critic = heads.actor, heads.critic

    def get_states(self, x, gru_state, first):
        # x: the stored inputs [T*B, ..]; first [T*B]: the obs starts an episode (memory from zeros)
        h = self.above(x["visual"], x["gesture"], x["target"], x["pose"], x["gesture_id"])
        batch = gru_state.shape[1]
        h = h.reshape((-1, batch, h.shape[-1]))
        first = first.reshape((-1, batch))
        # one GRU call per stretch of steps in which no env of the batch starts an episode (the
        # same as one call per step, with the memory zeroed where an episode starts)
        starts = [0] + [t for t in range(1, len(first)) if bool(first[t].any())] + [len(first)]
        out = []
        for a, b in zip(starts[:-1], starts[1:]):
            y, gru_state = self.gru(h[a:b], (1.0 - first[a]).view(1, -1, 1) * gru_state)
            out += [y]
        return torch.flatten(torch.cat(out), 0, 1), gru_state

    def get_value(self, x, gru_state, first):
        hidden, _ = self.get_states(x, gru_state, first)
        return self.critic(hidden)

    def get_action_and_value(self, x, gru_state, first, action=None):
        hidden, gru_state = self.get_states(x, gru_state, first)
        probs = Categorical(logits=self.actor(hidden))
        if action is None:
            action = probs.sample()
        return action, probs.log_prob(action), probs.entropy(), self.critic(hidden), gru_state


class Inputs:
    """A vector env's current step in the stored form: the frozen encoder's features (computed
    here, once), the masked gesture with its id, the target and the person's pose."""

    def __init__(self, encoder, num_envs):
        self.encoder = encoder
        self.ids = GestureIds(num_envs)

    def __call__(self, vec):
        p = policy_inputs(vec)
        return {
            "visual": net.encoder_features(self.encoder, p["rgb"], p["depth"]),
            "gesture": torch.from_numpy(p["gesture"]),
            "gesture_id": torch.from_numpy(self.ids(p["gesture"])),
            "target": torch.from_numpy(p["target"]),
            "pose": torch.from_numpy(p["pose"]),
        }


def main():
    args = parse_args()
    batch_size = args.num_envs * args.num_steps
    minibatch_envs = args.num_envs // args.num_minibatches
    num_iterations = -(-args.total_timesteps // batch_size)  # 0: evaluate out/agent.pt only
    os.makedirs(args.out, exist_ok=True)
    print(json.dumps(dataclasses.asdict(args)), flush=True)

    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.torch_threads)

    envs = gesthor.make_vec(
        split="train", num_envs=args.num_envs, method=args.method, dataset=args.dataset, config=args.config, seed=args.seed
    )
    encoder = net.load_encoder(args.encoder_weights)
    inputs = Inputs(encoder, args.num_envs)
    agent = Agent(args.hidden)
    optimizer = optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)
    if num_iterations == 0:
        agent.load_state_dict(torch.load(os.path.join(args.out, "agent.pt")))

    # storage, as the default's rollout: the encoder's features, the gesture in half precision
    T, N = args.num_steps, args.num_envs
    obs_buf = {
        "visual": torch.zeros((T, N, 64, 8, 8)),
        "gesture": torch.zeros((T, N, 100, 95), dtype=torch.float16),
        "gesture_id": torch.zeros((T, N), dtype=torch.long),
        "target": torch.zeros((T, N), dtype=torch.long),
        "pose": torch.zeros((T, N, 3)),
    }
    actions = torch.zeros((T, N), dtype=torch.long)
    logprobs = torch.zeros((T, N))
    rewards = torch.zeros((T, N))
    terms = torch.zeros((T, N))
    dones = torch.zeros((T, N))
    firsts = torch.zeros((T, N))
    valid = torch.zeros((T, N))
    values = torch.zeros((T, N))

    global_step = 0
    start_time = time.time()
    collect_s = update_s = 0.0
    envs.reset(seed=args.seed)
    next_obs = inputs(envs)
    next_first = torch.ones(N)
    next_final = torch.zeros(N)  # the obs is an episode's final one: its action is ignored
    next_gru_state = torch.zeros(1, N, args.hidden)
    episodes = []
    log = open(os.path.join(args.out, "updates.jsonl"), "w")

    for iteration in range(1, num_iterations + 1):
        initial_gru_state = next_gru_state.clone()
        if args.anneal_lr:
            frac = 1.0 - (iteration - 1.0) / num_iterations
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        t0 = time.time()
        for step in range(T):
            global_step += N
            for k in obs_buf:
                obs_buf[k][step] = next_obs[k]
            firsts[step] = next_first
            valid[step] = 1.0 - next_final

            with torch.no_grad():
                action, logprob, _, value, next_gru_state = agent.get_action_and_value(next_obs, next_gru_state, next_first)
                values[step] = value.flatten()
            actions[step] = action
            logprobs[step] = logprob

            _, reward, terminations, truncations, infos = envs.step(action.numpy())
            done = np.logical_or(terminations, truncations)
            rewards[step] = torch.from_numpy(reward)
            terms[step] = torch.from_numpy(terminations.astype(np.float32))
            dones[step] = torch.from_numpy(done.astype(np.float32))
            next_obs = inputs(envs)
            next_first, next_final = next_final, torch.from_numpy(done.astype(np.float32))
            if "_success" in infos:
                for i in np.flatnonzero(infos["_success"]):
                    episodes.append((bool(infos["success"][i]), float(infos["episode_return"][i])))
        collect_s += time.time() - t0

        t0 = time.time()
        # GAE over valid transitions: a chain stops where the next obs is an episode's final
        # one (that transition is masked); a terminated episode bootstraps 0, a truncated one
        # the value of its final obs (the next step's value)
        with torch.no_grad():
            next_value = agent.get_value(next_obs, next_gru_state, next_first).reshape(1, -1)
            advantages = torch.zeros_like(rewards)
            lastgaelam = 0
            for t in reversed(range(T)):
                nextvalues = next_value if t == T - 1 else values[t + 1]
                delta = rewards[t] + args.gamma * nextvalues * (1.0 - terms[t]) - values[t]
                advantages[t] = lastgaelam = delta + args.gamma * args.gae_lambda * (1.0 - dones[t]) * lastgaelam
            returns = advantages + values

        b_obs = {k: v.reshape((-1,) + v.shape[2:]) for k, v in obs_buf.items()}
        b_logprobs = logprobs.reshape(-1)
        b_actions = actions.reshape(-1)
        b_firsts = firsts.reshape(-1)
        b_valid = valid.reshape(-1)
        b_advantages = advantages.reshape(-1)
        b_returns = returns.reshape(-1)
        b_values = values.reshape(-1)

        # minibatches of whole envs, so the GRU sees each env's sequence in order; the ids say
        # which rows show the same gesture (ids of different envs never meet)
        envinds = np.arange(N)
        flatinds = np.arange(batch_size).reshape(T, N)
        clipfracs = []
        for epoch in range(args.update_epochs):
            np.random.shuffle(envinds)
            for start in range(0, N, minibatch_envs):
                mbenvinds = envinds[start : start + minibatch_envs]
                mb_inds = flatinds[:, mbenvinds].ravel()  # time-major, as get_states reads it
                mb_obs = {k: v[mb_inds] for k, v in b_obs.items()}
                _, newlogprob, entropy, newvalue, _ = agent.get_action_and_value(
                    mb_obs, initial_gru_state[:, mbenvinds], b_firsts[mb_inds], b_actions[mb_inds]
                )
                m = b_valid[mb_inds]
                msum = m.sum().clamp(min=1.0)
                logratio = newlogprob - b_logprobs[mb_inds]
                ratio = logratio.exp()

                with torch.no_grad():
                    approx_kl = (((ratio - 1) - logratio) * m).sum() / msum
                    clipfracs += [(((ratio - 1.0).abs() > args.clip_coef).float() * m).sum().item() / msum.item()]

                mb_advantages = b_advantages[mb_inds]
                if args.norm_adv:
                    mean = (mb_advantages * m).sum() / msum
                    std = (((mb_advantages - mean) ** 2 * m).sum() / msum).sqrt()
                    mb_advantages = (mb_advantages - mean) / (std + 1e-8)

                pg_loss1 = -mb_advantages * ratio
                pg_loss2 = -mb_advantages * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)
                pg_loss = (torch.max(pg_loss1, pg_loss2) * m).sum() / msum

                newvalue = newvalue.view(-1)
                if args.clip_vloss:
                    v_loss_unclipped = (newvalue - b_returns[mb_inds]) ** 2
                    v_clipped = b_values[mb_inds] + torch.clamp(
                        newvalue - b_values[mb_inds], -args.clip_coef, args.clip_coef
                    )
                    v_loss_clipped = (v_clipped - b_returns[mb_inds]) ** 2
                    v_loss = 0.5 * (torch.max(v_loss_unclipped, v_loss_clipped) * m).sum() / msum
                else:
                    v_loss = 0.5 * (((newvalue - b_returns[mb_inds]) ** 2) * m).sum() / msum

                entropy_loss = (entropy * m).sum() / msum
                loss = pg_loss - args.ent_coef * entropy_loss + v_loss * args.vf_coef

                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
        update_s += time.time() - t0

        recent = episodes[-100:]
        record = {
            "iteration": iteration,
            "frames": global_step,
            "sps": global_step / (time.time() - start_time),
            "collect_sps": global_step / collect_s,
            "update_s": update_s / iteration,
            "lr": optimizer.param_groups[0]["lr"],
            "value_loss": v_loss.item(),
            "policy_loss": pg_loss.item(),
            "entropy": entropy_loss.item(),
            "approx_kl": approx_kl.item(),
            "clipfrac": float(np.mean(clipfracs)),
            "episodes": len(episodes),
            "success_rate": float(np.mean([e[0] for e in recent])) if recent else 0.0,
        }
        log.write(json.dumps(record) + "\n")
        log.flush()
        print(
            f"iter {iteration}/{num_iterations} frames {global_step} SPS {record['sps']:.0f} "
            f"(collect {record['collect_sps']:.0f}/s, update {record['update_s']:.2f} s/rollout) "
            f"success {record['success_rate']:.2f} entropy {record['entropy']:.3f}",
            flush=True,
        )

    wall = time.time() - start_time
    envs.close()
    if num_iterations:
        torch.save(agent.state_dict(), os.path.join(args.out, "agent.pt"))

    # SR at the first stop on the val programs `orchestrator eval --max-programs` picks,
    # sampling from the policy as `orchestrator eval` does without --greedy
    programs = val_programs(args.dataset, args.eval_programs)
    vec = gesthor.make_vec(
        split="val", num_envs=args.eval_envs, method=args.method, dataset=args.dataset, config=args.config,
        seed=SEED, programs=programs, overrides=["run.scenes=[]"],
    )
    state = torch.zeros(1, args.eval_envs, args.hidden)
    eval_inputs = Inputs(encoder, args.eval_envs)

    def act(obs, first):
        # reads the vector's buffers: the step `obs` came from
        nonlocal state
        with torch.no_grad():
            x = eval_inputs(vec)
            a, _, _, _, state = agent.get_action_and_value(x, state, torch.from_numpy(first.astype(np.float32)))
        return a.numpy()

    ev = evaluate(vec, act, programs, finished=vec._pool.finished)
    vec.close()
    result = {
        "trainer": "CleanRL-style PPO",
        "frames": global_step,
        "train_seconds": wall,
        "fps": global_step / wall,
        "collect_fps": global_step / max(collect_s, 1e-9),
        "collect_seconds": collect_s,
        "update_seconds": update_s,
        "update_s_per_batch": update_s / max(num_iterations, 1),
        "batch": batch_size,
        "eval": ev,
    }
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
