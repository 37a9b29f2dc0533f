//! A request to stop long work early, from another thread: the Python
//! binding sets it on Ctrl-C so that `refine` and `estimate` end at their
//! next refinement step instead of after all of them. Work that honours it
//! returns [`Error::Stopped`]; what it had done is dropped.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::error::{Error, Result};

/// A shared stop flag; clones share it. The default is never set.
#[derive(Clone, Debug, Default)]
pub struct Stop(Arc<AtomicBool>);

impl Stop {
    /// Asks the work holding a clone to stop at its next check.
    pub fn request(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    pub fn requested(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// `Err(Error::Stopped)` once a stop was requested: called between
    /// steps of long work.
    pub fn check(&self) -> Result<()> {
        if self.requested() { Err(Error::Stopped) } else { Ok(()) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clones_share_the_flag() {
        let a = Stop::default();
        let b = a.clone();
        assert!(a.check().is_ok());
        b.request();
        assert!(a.requested());
        assert!(matches!(a.check(), Err(Error::Stopped)));
    }
}
