//! A second thread for tracking several probes in one frame: it runs one closure
//! while the calling thread runs another, both borrowing the caller's data, and
//! allocates nothing per call (one mutex, two condition variables, one thread kept
//! for the tracker's life).

use std::any::Any;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

/// The closure handed over, its lifetime erased: [`SecondThread::join`] waits until
/// the second thread has finished with it before the closure goes out of scope.
struct Job(*mut (dyn FnMut() + Send + 'static));

// SAFETY: the closure behind the pointer is `Send`, and only the second thread
// touches it between its hand-over and the end of its run.
unsafe impl Send for Job {}

#[derive(Default)]
struct Slot {
    job: Option<Job>,
    /// The last job handed over has run (or panicked with `panic`).
    done: bool,
    panic: Option<Box<dyn Any + Send>>,
    quit: bool,
}

#[derive(Default)]
struct Shared {
    slot: Mutex<Slot>,
    posted: Condvar,
    finished: Condvar,
}

fn lock(shared: &Shared) -> MutexGuard<'_, Slot> {
    // A panic never happens with the lock held: the jobs run outside it.
    shared.slot.lock().unwrap_or_else(|e| e.into_inner())
}

/// One thread beside the caller's, kept until dropped.
#[derive(Debug)]
pub struct SecondThread {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Shared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Shared")
    }
}

impl SecondThread {
    /// Starts the thread, named `name`.
    pub fn spawn(name: &str) -> std::io::Result<SecondThread> {
        let shared = Arc::new(Shared::default());
        let theirs = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name(name.to_string())
            .spawn(move || serve(&theirs))?;
        Ok(SecondThread {
            shared,
            thread: Some(thread),
        })
    }

    /// Runs `theirs` on the second thread and `mine` on this one, and returns when both
    /// have; a panic in either is resumed here once both have ended.
    pub fn join<A: FnOnce() + Send, B: FnOnce()>(&self, theirs: A, mine: B) {
        let mut theirs = Some(theirs);
        let mut call = move || {
            if let Some(f) = theirs.take() {
                f()
            }
        };
        let job: *mut (dyn FnMut() + Send + '_) = &mut call;
        // SAFETY: only the lifetime is erased. `call` lives on this stack frame until
        // `Wait` below has seen the job done, which it waits for on every way out of
        // this function, unwinding included.
        let job: *mut (dyn FnMut() + Send + 'static) = unsafe { std::mem::transmute(job) };
        {
            let mut slot = lock(&self.shared);
            slot.job = Some(Job(job));
            slot.done = false;
        }
        self.shared.posted.notify_one();
        let wait = Wait(&self.shared);
        mine();
        let panic = wait.finish();
        if let Some(payload) = panic {
            resume_unwind(payload);
        }
    }
}

/// Waits for the job handed over to be done, when finished or dropped.
struct Wait<'a>(&'a Shared);

impl Wait<'_> {
    fn finish(self) -> Option<Box<dyn Any + Send>> {
        let panic = self.wait();
        std::mem::forget(self);
        panic
    }

    fn wait(&self) -> Option<Box<dyn Any + Send>> {
        let mut slot = lock(self.0);
        while !slot.done {
            slot = self
                .0
                .finished
                .wait(slot)
                .unwrap_or_else(|e| e.into_inner());
        }
        slot.panic.take()
    }
}

impl Drop for Wait<'_> {
    fn drop(&mut self) {
        self.wait();
    }
}

/// The second thread's life: run each job handed over until told to quit.
fn serve(shared: &Shared) {
    let mut slot = lock(shared);
    loop {
        if let Some(Job(job)) = slot.job.take() {
            drop(slot);
            // SAFETY: `join` keeps the closure alive and untouched until `done`.
            let result = catch_unwind(AssertUnwindSafe(|| unsafe { (*job)() }));
            slot = lock(shared);
            slot.panic = result.err();
            slot.done = true;
            shared.finished.notify_all();
        } else if slot.quit {
            return;
        } else {
            slot = shared.posted.wait(slot).unwrap_or_else(|e| e.into_inner());
        }
    }
}

impl Drop for SecondThread {
    fn drop(&mut self) {
        lock(&self.shared).quit = true;
        self.shared.posted.notify_one();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_halves_run_on_borrowed_data() {
        let second = SecondThread::spawn("test-second").unwrap();
        let mut data = vec![0u64; 1000];
        for round in 1..=50u64 {
            let (a, b) = data.split_at_mut(500);
            let caller = std::thread::current().id();
            let mut other = None;
            second.join(
                || {
                    a.iter_mut().for_each(|x| *x += round);
                    other = Some(std::thread::current().id());
                },
                || b.iter_mut().for_each(|x| *x += 2 * round),
            );
            assert_ne!(
                other,
                Some(caller),
                "the first half runs on the second thread"
            );
        }
        let sum: u64 = (1..=50).sum();
        assert!(data[..500].iter().all(|&x| x == sum));
        assert!(data[500..].iter().all(|&x| x == 2 * sum));
    }

    #[test]
    fn a_panic_on_the_second_thread_reaches_the_caller_after_both_end() {
        let second = SecondThread::spawn("test-second").unwrap();
        let mut mine_ran = false;
        let result = catch_unwind(AssertUnwindSafe(|| {
            second.join(|| panic!("theirs"), || mine_ran = true);
        }));
        assert!(result.is_err());
        assert!(mine_ran);
        // The thread serves the next job.
        let mut ran = false;
        second.join(|| ran = true, || {});
        assert!(ran);
    }
}
