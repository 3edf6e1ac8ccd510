"""Contact-aware encoder: learned messages from the relative geometry and motion of pairs.

The paper's graph operation averages neighbours' features with scalar weights, so it cannot
express "pushed away from neighbour j along r_ij". In these overdamped suspensions a particle's
velocity is the local flow plus the contact and cohesion forces on it over the drag
coefficient (docs/spec/model.md#what-the-encoder-sees), and those forces are set by the gaps to its
neighbours (overlaps of ~1e-5 d for the linear spring, gaps below 0.1 d for cohesion) and change as
the flow closes and opens those gaps. This encoder gives every pair what it needs to learn that:

- edge inputs: the LE-aware minimum-image vector ``r_ij`` over the cut-off, the surface gap
  ``g = |r_ij| - d`` (computed in float64 before the cast, :mod:`gripdem.data.graph`) in three
  transforms that make contact-scale gaps order one (``tanh(g / 0.005)``, ``g / 0.1`` and a
  signed log resolving overlaps from 1e-5 d), and the pair's relative flow-relative
  displacements over the last ``edge_history`` steps with their normal components;
- node inputs: the particle's own flow-relative displacement history (and the x-position
  features where the driving depends on x, the periodic scene's body force);
- ``rounds`` of message passing with learned message, edge-update and node-update MLPs
  (residual), sums over neighbours;
- for an ensemble member (``noise_channels > 0``), a per-particle latent noise vector
  ``z ~ N(0, I)`` whose learned linear embedding is added to the node latents before every
  round and to the output: the noise conditions every message a particle sends and receives,
  so one forward pass draws one sample of the whole configuration's next frames. Per-node
  work only (no edge term changes): a member costs what the deterministic forward costs. With
  ``z = 0`` the encoder is exactly the deterministic one with the same weights.

Everything is relative (pair vectors, relative motion), so the encoder is permutation-
equivariant, works for any particle count, and is invariant to an LE-consistent shift of the
whole configuration (without the x-position features, which the periodic drive needs).

Shapes: ``history (batch, particles, K, 3)`` in velocity units, ``static (batch, particles, S)``,
a :class:`ContactGraph` over ``batch * particles`` nodes, optional ``noise (batch, particles,
noise_channels)``; output ``(batch, particles, 1, channels)`` (one time step for the seq2seq
GRU block).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

#: gap scales (in diameters) of the edge transforms: contact / near contact, cohesion range
CONTACT_GAP_SCALE = 0.005
COHESION_GAP_SCALE = 0.1
#: smallest gap resolved by the signed-log transform (contact overlaps are ~1e-5 d)
LOG_GAP_FLOOR = 1e-5
LOG_GAP_RANGE = math.log1p(1e-1 / LOG_GAP_FLOOR)
#: where an ensemble member's latent noise enters (see ContactEncoder)
NOISE_INTO = ("rounds", "input", "head")


@dataclass
class ContactGraph:
    """Pairs ``(i, j)``, ``i != j``, over ``n_nodes`` flattened nodes (``b * particles + p``).

    edge_index ``(2, E)`` (receiver i, neighbour j); vector ``(E, 3)`` minimum-image
    ``r_j - r_i`` in diameters; gap ``(E,)`` surface gap in diameters; cutoff in diameters.
    """

    edge_index: torch.Tensor
    vector: torch.Tensor
    gap: torch.Tensor
    cutoff: float
    n_nodes: int


def gap_features(gap: torch.Tensor) -> torch.Tensor:
    """``(E,)`` gaps in diameters -> ``(E, 3)`` order-one transforms (see module doc)."""
    signed_log = torch.sign(gap) * torch.log1p(gap.abs() / LOG_GAP_FLOOR) / LOG_GAP_RANGE
    return torch.stack(
        [torch.tanh(gap / CONTACT_GAP_SCALE), gap / COHESION_GAP_SCALE, signed_log], dim=-1
    )


def mlp(n_in: int, hidden: int, n_out: int) -> nn.Sequential:
    """Two layers with SiLU. (A LayerNorm on the outputs, as learned simulators use, measured
    worse here: 0.84 vs 0.80 of CV's RMSE at 190-10 pbc; it removes the message magnitude.)"""
    return nn.Sequential(nn.Linear(n_in, hidden), nn.SiLU(), nn.Linear(hidden, n_out))


class PairMLP(nn.Module):
    """``MLP([h_i, h_j, x_ij])`` for every edge without building the ``(E, 3C)``
    concatenation: the first layer is split into ``A h`` and ``B h`` computed once per node
    (gathered per edge) plus ``W x_ij`` per edge; the same function, a third of the work."""

    def __init__(self, channels: int, edge_channels: int, hidden: int, n_out: int):
        super().__init__()
        self.receiver = nn.Linear(channels, hidden)
        self.sender = nn.Linear(channels, hidden, bias=False)
        self.edge = nn.Linear(edge_channels, hidden, bias=False)
        self.out = nn.Linear(hidden, n_out)

    def node_terms(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """h ``(nodes, C)`` -> the first layer's receiver and sender terms, ``(nodes, hidden)``
        each (computed once per node, gathered per edge by :meth:`edges`)."""
        return self.receiver(h), self.sender(h)

    def edges(
        self, terms: tuple[torch.Tensor, torch.Tensor], x: torch.Tensor, edge_index: torch.Tensor
    ) -> torch.Tensor:
        """:meth:`node_terms`, x ``(E, C_e)``, edge_index ``(2, E)`` -> ``(E, n_out)`` (any
        subset of the edges: the rows of ``x`` and the columns of ``edge_index`` agree)."""
        i, j = edge_index
        # index_select, not h[i]: its backward is an index_add, advanced indexing's is a
        # much slower accumulating index_put on the CPU; the sums go in place into the edge
        # term (no (E, hidden) temporaries; addition needs no saved inputs for autograd)
        first = self.edge(x)
        first += terms[0].index_select(0, i)
        first += terms[1].index_select(0, j)
        # in place where no gradient is taken (the activation's input is not kept)
        return self.out(nn.functional.silu(first, inplace=not torch.is_grad_enabled()))

    def forward(self, h: torch.Tensor, x: torch.Tensor, edge_index: torch.Tensor) -> torch.Tensor:
        """h ``(nodes, C)``, x ``(E, C_e)``, edge_index ``(2, E)`` -> ``(E, n_out)``."""
        return self.edges(self.node_terms(h), x, edge_index)


class ContactEncoder(nn.Module):
    """Message passing on the contact graph (see module docstring).

    Args:
        history_len: K, displacement steps per particle.
        static_features: S, per-particle features besides the history (0 if none).
        channels: latent size of nodes and edges.
        rounds: message-passing rounds.
        edge_history: relative-motion steps per pair (the last ones, <= K).
        edge_updates: update the edge latents between rounds (False: every round reads the
            encoded edge inputs; ~40 % fewer pair evaluations).
        noise_channels: size of the per-particle latent noise of an ensemble member (0: a
            deterministic encoder).
        noise_into: where the noise's embeddings are added to the node latents: ``rounds``
            (before every round and to the output), ``input`` (before the first round only)
            or ``head`` (to the output only: the message passing stays deterministic).
        noise_neighbours: each particle's noise is its own plus its graph neighbours', over
            ``sqrt(1 + neighbours)`` (unit variance): neighbours share part of their noise, so
            touching particles can be moved together.
        pair_channels: width of the pair latents and of the pair MLPs' hidden layers (None:
            ``channels``). The per-edge products scale with its square: 32 of 64 channels is a
            quarter of the edge work; the node latents keep ``channels``.

    Run time (not hyperparameters): :attr:`edge_chunk` edges per block when no gradient is
    taken (0: all at once) and the weights' dtype (``encoder.to(torch.bfloat16)`` computes in
    bf16; the edge inputs are formed in the inputs' dtype first, the output is cast back).
    """

    #: edges per block of a round with edge updates, without gradients: the block's edge
    #: latents stay in cache (experiments/benchmarks/model_cost/encoder_speed.py --chunks:
    #: 1024-8192 the same within noise, 2.3x faster than all at once at 32 000 particles,
    #: 16 384 slower); 0 processes all at once
    EDGE_CHUNK = 4096
    #: the same for the folded rounds (no edge updates: one product and a sum per edge, no
    #: latents to keep): larger blocks pay, measured (bf16, one thread) 7-10 % faster than
    #: 4096 from 2000 to 64 000 particles, all at once within 3 % below 32 000 particles; the
    #: blocks bound the temporaries' memory
    FOLDED_EDGE_CHUNK = 32768

    def __init__(
        self,
        history_len: int,
        static_features: int = 0,
        channels: int = 64,
        rounds: int = 3,
        edge_history: int = 3,
        edge_updates: bool = True,
        noise_channels: int = 0,
        noise_into: str = "rounds",
        noise_neighbours: bool = False,
        pair_channels: int | None = None,
    ):
        super().__init__()
        if rounds < 1:
            raise ValueError(f"contact encoder needs rounds >= 1, got {rounds}")
        self.history_len = int(history_len)
        self.static_features = int(static_features)
        self.edge_history = max(1, min(int(edge_history), self.history_len))
        m = self.edge_history
        c = int(channels)
        pc = c if pair_channels is None else int(pair_channels)
        if pc < 1:
            raise ValueError(f"pair_channels must be >= 1 (or None: channels), got {pair_channels}")
        self.edge_chunk = self.EDGE_CHUNK if edge_updates else self.FOLDED_EDGE_CHUNK
        self.node_in = mlp(3 * self.history_len + self.static_features, c, c)
        self.edge_in = mlp(3 + 3 + 4 * m, pc, pc)
        self.message = nn.ModuleList(PairMLP(c, pc, pc, pc) for _ in range(rounds))
        # the edges are updated between rounds (the last round's update would be unused)
        self.edge_update = nn.ModuleList(
            PairMLP(c, pc, pc, pc) for _ in range(rounds - 1 if edge_updates else 0)
        )
        self.node_update = nn.ModuleList(mlp(c + pc, c, c) for _ in range(rounds))
        self.noise_channels = int(noise_channels)
        if self.noise_channels < 0:
            raise ValueError(f"noise_channels must be >= 0, got {noise_channels}")
        if noise_into not in NOISE_INTO:
            raise ValueError(f"noise_into must be one of {NOISE_INTO}, got {noise_into!r}")
        self.noise_into = noise_into
        self.noise_neighbours = bool(noise_neighbours)
        # the places (round index, `rounds`: the output) where an embedding of the noise is
        # added; default init: the members differ from the first step, so the CRPS's spread
        # term has a gradient
        places = {"rounds": range(rounds + 1), "input": [0], "head": [rounds]}[noise_into]
        self.noise_places = list(places) if self.noise_channels else []
        self.noise_embedding = nn.ModuleList(
            nn.Linear(self.noise_channels, c, bias=False) for _ in self.noise_places
        )

    @property
    def out_channels(self) -> int:
        return self.node_in[-1].out_features

    #: the seq2seq block reads one feature vector per particle (see gripdem.nn.seq2seq)
    context = "vector"

    def edge_inputs(self, history: torch.Tensor, graph: ContactGraph) -> torch.Tensor:
        """``(E, 6 + 4M)``: vector / cut-off, gap transforms, relative motion of the last M
        steps (vector and normal component)."""
        i, j = graph.edge_index
        vector = graph.vector.to(history.dtype)
        distance = vector.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        recent = history[:, -self.edge_history :]  # (nodes, M, 3)
        relative = recent.index_select(0, j) - recent.index_select(0, i)  # (E, M, 3)
        normal = torch.einsum("emc,ec->em", relative, vector / distance)
        return torch.cat(
            [
                vector / graph.cutoff,
                gap_features(graph.gap.to(history.dtype)),
                relative.flatten(1),
                normal,
            ],
            dim=-1,
        )

    def forward(
        self,
        history: torch.Tensor,
        static: torch.Tensor | None,
        graph: ContactGraph,
        noise: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """history ``(B, N, K, 3)``, static ``(B, N, S)`` or None, noise ``(B, N, Z)`` or None
        (zero) -> ``(B, N, 1, channels)``."""
        b, n, k, _ = history.shape
        dtype = self.node_in[0].weight.dtype
        if k != self.history_len:
            raise ValueError(f"encoder built for history {self.history_len}, got {k}")
        if graph.n_nodes != b * n:
            raise ValueError(f"graph has {graph.n_nodes} nodes, features have {b}x{n}")
        flat = history.reshape(b * n, k, 3)
        node = flat.reshape(b * n, 3 * k)
        if self.static_features:
            if static is None or static.shape[-1] != self.static_features:
                raise ValueError(f"encoder expects {self.static_features} static features")
            node = torch.cat([node, static.reshape(b * n, -1).to(node.dtype)], dim=-1)
        h = self.node_in(node.to(dtype))
        edge_x = self.edge_inputs(flat, graph).to(dtype)
        # without edge updates every round reads the edge MLP's output through its own linear
        # first layer: both linear maps fold into one (see _summed_messages), so the rounds
        # start from the edge MLP's hidden layer
        folded = not self.edge_update
        if folded:
            e = nn.functional.silu(self.edge_in[0](edge_x), inplace=not torch.is_grad_enabled())
        else:
            e = self.edge_in(edge_x)
        z = self._noise(noise, b, n)
        index = graph.edge_index
        shared = z is not None and self.noise_neighbours
        degree = self._degree(index[0], h) if folded or shared else None
        if shared:
            z = z.index_add(0, index[0], z.index_select(0, index[1])) / torch.sqrt(1 + degree)
        for r, (message, node_update) in enumerate(
            zip(self.message, self.node_update, strict=True)
        ):
            if z is not None and r in self.noise_places:
                h = h + self.noise_embedding[self.noise_places.index(r)](z)
            if folded:
                incoming = self._summed_messages(message, h, e, index, degree)
            else:
                incoming, e = self._pairs(
                    message, self.edge_update[r] if r < len(self.edge_update) else None, h, e, index
                )
            h = h + node_update(torch.cat([h, incoming], dim=-1))
        if z is not None and len(self.message) in self.noise_places:
            h = h + self.noise_embedding[-1](z)
        return h.reshape(b, n, 1, -1).to(history.dtype)

    @staticmethod
    def _degree(receivers: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """Edges per receiving node ``(nodes, 1)`` in the latents' dtype."""
        count = torch.bincount(receivers, minlength=h.shape[0])
        return count.to(h.dtype)[:, None]

    def _summed_messages(
        self,
        message: PairMLP,
        h: torch.Tensor,
        hidden: torch.Tensor,
        index: torch.Tensor,
        degree: torch.Tensor,
    ) -> torch.Tensor:
        """One round's summed incoming messages ``(nodes, P)`` from h ``(nodes, C)`` and the
        edge MLP's hidden layer ``(E, P)`` (no edge updates), with no product per edge but one:

        - the edge MLP's output layer ``e = W2 a + b2`` and the message's edge term ``We e``
          are both linear, so ``We e = (We W2) a + We b2``; the bias is per round, added to
          the receiver's node term;
        - the message's output layer is linear too, so the sum over a receiver's edges
          ``sum_j (Wo s_ij + bo) = Wo (sum_j s_ij) + deg_i bo`` is taken over the hidden
          activations ``s_ij`` and the output layer runs once per node.

        The same function as :meth:`PairMLP.forward` summed with ``index_add`` (the rounding
        differs). Without gradients the edges go in blocks of :attr:`edge_chunk`."""
        out_layer = self.edge_in[-1]
        edge_weight = message.edge.weight @ out_layer.weight  # (P, P)
        receiver, sender = message.node_terms(h)
        receiver = receiver + message.edge.weight @ out_layer.bias
        n_edges = index.shape[1]
        grad = torch.is_grad_enabled()
        chunk = n_edges if grad or self.edge_chunk <= 0 else int(self.edge_chunk)
        summed = h.new_zeros(h.shape[0], edge_weight.shape[0])
        for start in range(0, max(n_edges, 1), max(chunk, 1)):
            block = slice(start, start + chunk)
            i, j = index[0, block], index[1, block]
            first = hidden[block] @ edge_weight.T
            if grad:
                first = first + receiver.index_select(0, i) + sender.index_select(0, j)
                summed = summed.index_add(0, i, nn.functional.silu(first))
            else:  # in place: no temporaries per block
                first += receiver.index_select(0, i)
                first += sender.index_select(0, j)
                summed.index_add_(0, i, nn.functional.silu(first, inplace=True))
        return nn.functional.linear(summed, message.out.weight) + degree * message.out.bias

    def _pairs(
        self,
        message: PairMLP,
        update: PairMLP | None,
        h: torch.Tensor,
        e: torch.Tensor,
        index: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One round's pair work: h ``(nodes, C)``, e ``(E, P)`` -> the summed incoming
        messages ``(nodes, P)`` and the (updated) edge latents ``(E, P)``. Without gradients
        the edges go in blocks of :attr:`edge_chunk` (each block's message, edge update and
        sum while its latents are in cache; the edge latents are updated in place): the same
        sums in another order, equal to round-off."""
        terms = message.node_terms(h)
        update_terms = None if update is None else update.node_terms(h)
        n_edges = index.shape[1]
        chunk = int(self.edge_chunk)
        incoming = h.new_zeros(h.shape[0], message.out.out_features)
        if torch.is_grad_enabled() or chunk <= 0 or n_edges <= chunk:
            msg = message.edges(terms, e, index)
            if update_terms is not None:
                e = e + update.edges(update_terms, msg, index)
            return incoming.index_add_(0, index[0], msg), e
        for start in range(0, n_edges, chunk):
            block = slice(start, start + chunk)
            idx = index[:, block]
            msg = message.edges(terms, e[block], idx)
            if update_terms is not None:
                e[block] += update.edges(update_terms, msg, idx)
            incoming.index_add_(0, idx[0], msg)
        return incoming, e

    def _noise(self, noise: torch.Tensor | None, b: int, n: int) -> torch.Tensor | None:
        """The noise as ``(B * N, Z)`` in the latents' dtype, or None (zero noise or a
        deterministic encoder)."""
        if noise is None:
            return None
        if not self.noise_channels:
            raise ValueError("this encoder is deterministic (noise_channels=0): it takes no noise")
        if tuple(noise.shape) != (b, n, self.noise_channels):
            raise ValueError(
                f"noise must be (batch, particles, noise_channels) = ({b}, {n}, "
                f"{self.noise_channels}), got {tuple(noise.shape)}"
            )
        return noise.reshape(b * n, self.noise_channels).to(self.node_in[0].weight.dtype)
