"""Asynchronous messages between ranks (``dgtd run --asynchronous`` under mpiexec): no rank waits for another
inside a block of steps.

At every step a rank posts its agents' messages to each neighbouring rank with a non-blocking send, stamped with
the step and the wall-clock time, and takes whatever has arrived so far (non-blocking receives, tested, not waited
for); each ghost (another rank's agent that this rank's agents hear) then carries the newest message received from
its rank that was sent at or before the receiver's own step (one sent later, by a rank that is ahead, waits in the
inbox until the receiver reaches its step), or the one it had at the start of the block when none has come yet.
MPI delivers the messages of one sender in the order sent, so the inbox of each neighbour is in step order. The age
of each message used, in steps (the receiver's step minus the sender's: 0 is what a synchronous run uses, k a message
k steps old), is counted per ghost and step, as is the time each message took to arrive.

``staleness`` S bounds the ages (stale synchronous parallel, Ho et al. 2013): a rank whose newest message from a
neighbour is more than S steps old waits for a newer one. S = 0 is the synchronous run, bit for bit; None never
waits.

At the end of the block every rank receives the rest of what was sent to it (each sends exactly one message per
step to each neighbour, so both ends know how many) and its sends complete: nothing is in flight across a block
end, where the ranks combine their metrics (`dgtd.backends.mpi.Ranks`) and checkpoints are taken.
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np

TAG = 25
AGE_BINS = 4096  # ages 0 .. AGE_BINS - 1 steps are counted each in its own bin; the last holds the rest
# This rank's counts since the run started (`dgtd.backends.mpi.message_ages` adds up the ranks'): ghosts used per
# age, and the messages received with their seconds in transit (sum and largest)
AGES = {"counts": np.zeros(AGE_BINS, np.int64), "transit": np.zeros(3)}


class Mailbox:
    """One block of ``steps`` asynchronous steps' messages between this rank (`Partition` ``P``) and its neighbours.

    ``start``: the messages of the block's first step (name -> (B, local, q)), whose ghost rows are the ghosts'
    owners' messages at the block start (stamped step 0). ``beat``: called whenever a message arrives."""

    def __init__(self, P, start: dict, steps: int, staleness: int | None, beat):
        self.P, self.steps, self.staleness, self.beat = P, steps, staleness, beat
        self.names = list(start)
        # the newest payload in use from each neighbouring rank, in the sender's layout (`_payload`), and its step
        self.newest = [self._payload(start, rows) for rows in P.recv]
        self.stamp = np.zeros(len(P.neighbours), np.int64)
        self.early: list = [deque() for _ in P.neighbours]  # (step, payload) received, not usable yet
        self.inbox = [np.empty(2 + len(x)) for x in self.newest]
        self.got = np.zeros(len(P.neighbours), np.int64)
        self.receiving = [self._listen(i) for i in range(len(P.neighbours))]
        self.sending: list = []  # (request, buffer): a buffer lives until its send completes

    @staticmethod
    def _payload(sent: dict, rows: np.ndarray) -> np.ndarray:
        return np.concatenate([np.zeros(0), *(x[:, rows].ravel() for x in sent.values())])

    def _listen(self, i: int):
        if self.got[i] >= self.steps:
            return None
        return self.P.comm.Irecv(self.inbox[i], source=self.P.neighbours[i], tag=TAG)

    def _arrived(self, i: int) -> None:
        stamp, sent_at = self.inbox[i][:2]
        late = time.time() - sent_at
        transit = AGES["transit"]
        transit[0], transit[1], transit[2] = transit[0] + 1, transit[1] + late, max(transit[2], late)
        self.early[i].append((int(stamp), self.inbox[i][2:].copy()))
        self.got[i] += 1
        self.receiving[i] = self._listen(i)
        self.beat()

    def _newest(self, i: int, t: int) -> None:
        """Neighbour i's newest message sent at or before step t, waiting while it is more than S steps old."""
        while True:
            while self.receiving[i] is not None and self.receiving[i].Test():
                self._arrived(i)
            while self.early[i] and self.early[i][0][0] <= t:
                self.stamp[i], self.newest[i] = self.early[i].popleft()
            if self.staleness is None or t - self.stamp[i] <= self.staleness:
                return
            self.receiving[i].Wait()  # a rank that never sends is `dgtd.backends.mpi.Watchdog`'s to end
            self._arrived(i)

    def swap(self, sent: dict, t: int) -> None:
        """Post this rank's rows of step t's messages ``sent`` to its neighbours; write into the ghost rows the newest
        usable (in place), and count their ages."""
        P = self.P
        now = time.time()
        for k, rows in zip(P.neighbours, P.send):
            buffer = np.concatenate([[t, now], self._payload(sent, rows)])
            self.sending.append((P.comm.Isend(buffer, dest=k, tag=TAG), buffer))
        self.sending = [(r, b) for r, b in self.sending if not r.Test()]
        for i, rows in enumerate(P.recv):
            self._newest(i, t)
            at = 0
            for name in self.names:
                x = sent[name]
                n = x.shape[0] * len(rows) * x.shape[2]
                x[:, rows] = self.newest[i][at : at + n].reshape(x.shape[0], len(rows), x.shape[2])
                at += n
            AGES["counts"][min(t - self.stamp[i], AGE_BINS - 1)] += len(rows)

    def finish(self) -> None:
        """Receive the rest of the block's messages and complete the sends: nothing is left in flight."""
        for i in range(len(self.P.neighbours)):
            while self.receiving[i] is not None:
                self.receiving[i].Wait()
                self._arrived(i)
        for request, _ in self.sending:
            request.Wait()
        self.sending = []
