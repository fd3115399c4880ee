//! A fixed-capacity FIFO between an interrupt and a lower-priority context, with no path
//! to a panic: the transmit queue of the HIL link (bytes) and the telemetry queue of the
//! control loop (frames).
//!
//! Why not `heapless::spsc` (0.9): its producer and consumer reach the buffer through an
//! unsized view, so every `len`, `enqueue` and `dequeue` computes `% n()` with a length
//! the compiler cannot see, and the images linked `panic_const_rem_by_zero` for it
//! (`.ci/no-panic` refuses any panic symbol). Here the ring's indices wrap by a compare
//! and a subtraction, every slot is reached through `get`/`get_mut`, and the ring is
//! shared through a critical section, so the code stays free of `unsafe`.
//!
//! The cost of that choice is a short critical section per operation: a few dozen
//! cycles for one item, and for [`Producer::enqueue_all`] a copy of the items (one
//! 45-byte answer of the HIL link). The control interrupt is the producer and has the
//! highest priority, so a critical section in the consumer delays it by at most that
//! much; it never waits otherwise. Every operation is bounded: no loop runs longer than
//! the items it is given.

use core::cell::RefCell;

use critical_section::Mutex;

/// The ring itself: `len` items from `head`, wrapping at `N`.
#[derive(Debug)]
struct Ring<T, const N: usize> {
    slots: [Option<T>; N],
    head: usize,
    len: usize,
}

impl<T: Copy, const N: usize> Ring<T, N> {
    /// The slot index `offset` items after the head (`offset < N`).
    fn index(&self, offset: usize) -> usize {
        // head < N and offset < N: one subtraction wraps it.
        let i = self.head + offset;
        if i >= N { i - N } else { i }
    }

    fn push(&mut self, item: T) -> Result<(), T> {
        if self.len >= N {
            return Err(item);
        }
        let i = self.index(self.len);
        match self.slots.get_mut(i) {
            Some(slot) => {
                *slot = Some(item);
                self.len += 1;
                Ok(())
            }
            None => Err(item),
        }
    }

    fn pop(&mut self) -> Option<T> {
        if self.len == 0 {
            return None;
        }
        let item = self.slots.get_mut(self.head)?.take()?;
        self.head = self.index(1);
        self.len -= 1;
        Some(item)
    }
}

/// A queue of at most `N` items of `T`, shared by one [`Producer`] and one
/// [`Consumer`] ([`split`](Self::split)).
#[derive(Debug)]
pub struct Queue<T, const N: usize> {
    ring: Mutex<RefCell<Ring<T, N>>>,
}

impl<T: Copy, const N: usize> Default for Queue<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Copy, const N: usize> Queue<T, N> {
    /// An empty queue.
    pub const fn new() -> Self {
        Queue { ring: Mutex::new(RefCell::new(Ring { slots: [None; N], head: 0, len: 0 })) }
    }

    /// The items it holds when full.
    pub const fn capacity(&self) -> usize {
        N
    }

    /// The producer and the consumer ends. Borrowing the queue mutably, it hands out
    /// one pair at a time (with a `&'static mut` queue, e.g. from
    /// `cortex_m::singleton!`, both ends are `'static`).
    pub fn split(&mut self) -> (Producer<'_, T, N>, Consumer<'_, T, N>) {
        let queue: &Self = self;
        (Producer { queue }, Consumer { queue })
    }

    /// Runs `f` on the ring in a critical section. The borrow never outlives the call
    /// and `f` never calls back here, so it cannot be taken twice; if it were, `f` is
    /// skipped and `otherwise` returned instead of a panic.
    fn with<R>(&self, otherwise: R, f: impl FnOnce(&mut Ring<T, N>) -> R) -> R {
        critical_section::with(|cs| match self.ring.borrow(cs).try_borrow_mut() {
            Ok(mut ring) => f(&mut ring),
            Err(_) => otherwise,
        })
    }

    fn len(&self) -> usize {
        self.with(0, |r| r.len)
    }
}

/// The end that adds items (the interrupt's).
#[derive(Debug)]
pub struct Producer<'a, T, const N: usize> {
    queue: &'a Queue<T, N>,
}

impl<T: Copy, const N: usize> Producer<'_, T, N> {
    /// Adds `item` at the back, or gives it back when the queue is full.
    pub fn enqueue(&mut self, item: T) -> Result<(), T> {
        self.queue.with(Err(item), |r| r.push(item))
    }

    /// Adds all of `items`, in order, or none of them (`false`) when they do not all
    /// fit: a half frame on a serial line would spoil the next one too.
    pub fn enqueue_all(&mut self, items: &[T]) -> bool {
        self.queue.with(false, |r| {
            if items.len() > N.saturating_sub(r.len) {
                return false;
            }
            items.iter().all(|&item| r.push(item).is_ok())
        })
    }

    /// Items in the queue.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// `true` when the queue holds no item.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The items it holds when full.
    pub const fn capacity(&self) -> usize {
        N
    }
}

/// The end that takes items (the lower-priority context's).
#[derive(Debug)]
pub struct Consumer<'a, T, const N: usize> {
    queue: &'a Queue<T, N>,
}

impl<T: Copy, const N: usize> Consumer<'_, T, N> {
    /// Takes the item at the front, if any.
    pub fn dequeue(&mut self) -> Option<T> {
        self.queue.with(None, Ring::pop)
    }

    /// `true` when an item is waiting.
    pub fn ready(&self) -> bool {
        !self.is_empty()
    }

    /// Items in the queue.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// `true` when the queue holds no item.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_in_first_out_across_the_wrap_and_full_is_refused() {
        let mut q: Queue<u16, 3> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let mut next_in = 0u16;
        let mut next_out = 0u16;
        // Fill and drain by different amounts so the head visits every slot.
        for round in 0..20 {
            let put = 1 + round % 3;
            for _ in 0..put {
                if tx.enqueue(next_in).is_ok() {
                    next_in += 1;
                }
            }
            assert!(tx.len() <= 3);
            let take = 1 + (round + 1) % 3;
            for _ in 0..take {
                match rx.dequeue() {
                    Some(x) => {
                        assert_eq!(x, next_out);
                        next_out += 1;
                    }
                    None => assert_eq!(next_out, next_in),
                }
            }
        }
        assert!(next_in > 20);
        // Full: the item comes back.
        while rx.dequeue().is_some() {}
        for k in 0..3 {
            assert_eq!(tx.enqueue(k), Ok(()));
        }
        assert_eq!(tx.enqueue(99), Err(99));
        assert_eq!((tx.len(), tx.capacity()), (3, 3));
        assert!(rx.ready());
    }

    #[test]
    fn enqueue_all_is_all_or_nothing() {
        let mut q: Queue<u8, 5> = Queue::new();
        let (mut tx, mut rx) = q.split();
        assert!(tx.enqueue_all(&[1, 2, 3]));
        assert!(!tx.enqueue_all(&[4, 5, 6]));
        assert_eq!(tx.len(), 3);
        assert!(tx.enqueue_all(&[4, 5]));
        assert!(!tx.enqueue_all(&[6]));
        assert!(tx.enqueue_all(&[]));
        let got: [Option<u8>; 6] = core::array::from_fn(|_| rx.dequeue());
        assert_eq!(got, [Some(1), Some(2), Some(3), Some(4), Some(5), None]);
        assert!(rx.is_empty() && !rx.ready());
    }
}
