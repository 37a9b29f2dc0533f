//! Upper-confidence-bound allocation of a refinement budget over hypotheses
//! (RIR, VeREFINE section 3.2): each round refines the hypothesis with the
//! highest `mean reward + c · sqrt(2 ln n / n_i)` (UCB1), trying every
//! hypothesis once first. With a discount γ < 1 (discounted UCB, for scenes
//! whose rewards drift as other objects move) every past observation's
//! weight decays by γ per round.

/// The bandit's state over `arms` hypotheses.
#[derive(Clone, Debug)]
pub struct Ucb {
    counts: Vec<f64>,
    sums: Vec<f64>,
    c: f64,
    gamma: f64,
}

impl Ucb {
    /// UCB1 with exploration constant `c` (the paper: 0.1) when `gamma` is
    /// 1, discounted UCB otherwise. Panics on no arms (a caller's bug).
    pub fn new(arms: usize, c: f64, gamma: f64) -> Ucb {
        assert!(arms > 0, "a bandit needs at least one arm");
        Ucb { counts: vec![0.0; arms], sums: vec![0.0; arms], c, gamma }
    }

    /// The arm to pull next: an untried one (lowest index) first, else the
    /// highest upper bound (ties to the lowest index).
    pub fn select(&self) -> usize {
        if let Some(i) = self.counts.iter().position(|&n| n == 0.0) {
            return i;
        }
        let total: f64 = self.counts.iter().sum();
        let bound = |i: usize| self.sums[i] / self.counts[i] + self.c * (2.0 * total.max(1.0).ln() / self.counts[i]).sqrt();
        (0..self.counts.len()).fold(0, |best, i| if bound(i) > bound(best) { i } else { best })
    }

    /// Records `reward` for `arm` (past observations decay by γ first).
    pub fn update(&mut self, arm: usize, reward: f64) {
        if self.gamma < 1.0 {
            self.counts.iter_mut().for_each(|n| *n *= self.gamma);
            self.sums.iter_mut().for_each(|s| *s *= self.gamma);
        }
        self.counts[arm] += 1.0;
        self.sums[arm] += reward;
    }

    /// Times each arm was pulled (discounted).
    pub fn counts(&self) -> &[f64] {
        &self.counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// On a toy bandit (Bernoulli arms 0.2, 0.5, 0.8) UCB1 spends most of a
    /// 2000-pull budget on the best arm, and every arm is tried.
    #[test]
    fn ucb1_allocates_most_pulls_to_the_best_arm() {
        let p = [0.2, 0.5, 0.8];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut b = Ucb::new(3, 0.5, 1.0);
        for _ in 0..2000 {
            let a = b.select();
            b.update(a, if rng.random::<f64>() < p[a] { 1.0 } else { 0.0 });
        }
        let n = b.counts();
        assert!(n.iter().all(|&k| k >= 1.0));
        assert!(n[2] > 0.8 * 2000.0, "{n:?}");
        assert!(n[0] < n[1], "{n:?}");
    }

    /// Untried arms come first, in order; with deterministic rewards the
    /// better arm is preferred; discounting follows a change of the best arm.
    #[test]
    fn untried_first_and_discounting_tracks_a_change() {
        let mut b = Ucb::new(2, 0.1, 1.0);
        assert_eq!(b.select(), 0);
        b.update(0, 0.3);
        assert_eq!(b.select(), 1);
        b.update(1, 0.9);
        assert_eq!(b.select(), 1);
        let mut d = Ucb::new(2, 0.1, 0.9);
        for _ in 0..50 {
            let a = d.select();
            d.update(a, if a == 0 { 0.9 } else { 0.1 });
        }
        // Arm 1 becomes the better one.
        let mut late = 0;
        for _ in 0..50 {
            let a = d.select();
            late += a;
            d.update(a, if a == 0 { 0.1 } else { 0.9 });
        }
        assert!(late > 30, "discounted UCB moved to the new best arm only {late} times");
    }
}
