"""`KeySampler`: the endless, resumable, sharded order in which a run reads the dataset's items."""

from collections.abc import Iterator

import torch
from torch import Tensor

from gaffer_diffusion.training.errors import DataError


class KeySampler(torch.utils.data.Sampler[int]):
    """An endless, resumable stream of item keys, sharded over processes.

    Position p (counted over all processes) maps to `key = epoch * n + perm_epoch[p % n]` with
    `epoch = p // n` and a permutation seeded by `(seed, epoch)`. Process `rank` of `world_size` takes
    positions `start + rank, start + rank + world_size, ...`.

    Args:
        num_items: n, the dataset length.
        seed: permutation seed.
        start: global position to start from (samples already consumed, for resuming).
        rank: this process's index.
        world_size: number of processes.
        shuffle: permute each epoch (False: identity order).
    """

    def __init__(
        self,
        num_items: int,
        *,
        seed: int = 0,
        start: int = 0,
        rank: int = 0,
        world_size: int = 1,
        shuffle: bool = True,
    ) -> None:
        if num_items < 1 or not 0 <= rank < world_size or start < 0:
            raise DataError(
                f"`KeySampler` got num_items={num_items}, rank={rank}, world_size={world_size}, "
                f"start={start}; need num_items >= 1, 0 <= rank < world_size, start >= 0."
            )
        self.num_items = num_items
        self.seed = seed
        self.start = start
        self.rank = rank
        self.world_size = world_size
        self.shuffle = shuffle

    def _perm(self, epoch: int) -> Tensor:
        if not self.shuffle:
            return torch.arange(self.num_items)
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        return torch.randperm(self.num_items, generator=g)

    def __iter__(self) -> Iterator[int]:
        p = self.start + self.rank
        epoch, perm = -1, torch.arange(0)
        while True:
            e = p // self.num_items
            if e != epoch:
                epoch, perm = e, self._perm(e)
            yield int(e * self.num_items + int(perm[p % self.num_items]))
            p += self.world_size
