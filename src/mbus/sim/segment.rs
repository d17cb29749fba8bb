//! One simulated M-Bus segment: the meters on a pair of wires. Request bytes in, the bytes
//! the master hears out (nothing, one answer, or the garble of several at once). Pure: time is
//! handed in.

use super::meter::{Behaviour, SimMeter};
use super::wire::{self, E5, Request};

/// The meters of one segment.
#[derive(Debug, Clone, Default)]
pub struct Segment {
    pub meters: Vec<SimMeter>,
}

/// Which meters a request's address reaches, and whether they answer.
enum Reach {
    /// These meters, answering.
    Answering(Vec<usize>),
    /// Every meter, none answering (broadcast 255).
    Silent,
}

impl Segment {
    /// A segment with these meters.
    pub fn new(meters: Vec<SimMeter>) -> Segment {
        Segment { meters }
    }

    /// What the master hears after sending `request` at time `now` (seconds): nothing, one
    /// meter's answer, or the collision of several.
    pub fn answer(&mut self, now: f64, request: &[u8]) -> Vec<u8> {
        let Some(request) = wire::read_request(request) else {
            return Vec::new();
        };
        match request {
            Request::Short { c: 0x40, a } => self.each(a, |m| {
                m.reset_link();
                if a == 0xFD {
                    m.selected = false;
                }
                vec![E5]
            }),
            Request::Short { c, a } if c & 0xCF == 0x4B => self.each(a, |m| m.req_ud2(now, c)),
            Request::Short { c, a } if c & 0xCF == 0x4A => self.each(a, |_| vec![E5]),
            Request::Long {
                c,
                a: 0xFD,
                ci: 0x52,
                data,
            } if c & 0xCF == 0x43 => self.select(&data),
            Request::Long { c, a, ci, .. } if c & 0xCF == 0x43 => self.each(a, |m| {
                if ci == 0x50 {
                    m.reset_application();
                }
                vec![E5]
            }),
            _ => Vec::new(),
        }
    }

    fn reach(&self, address: u8) -> Reach {
        let all = || (0..self.meters.len()).collect();
        match address {
            0xFF => Reach::Silent,
            0xFE => Reach::Answering(all()),
            0xFD => Reach::Answering(
                (0..self.meters.len())
                    .filter(|i| self.meters[*i].selected)
                    .collect(),
            ),
            a => Reach::Answering(
                (0..self.meters.len())
                    .filter(|i| self.meters[*i].address == a)
                    .collect(),
            ),
        }
    }

    /// Runs `act` on every meter `address` reaches and combines their answers.
    fn each(&mut self, address: u8, mut act: impl FnMut(&mut SimMeter) -> Vec<u8>) -> Vec<u8> {
        let (reached, answering) = match self.reach(address) {
            Reach::Answering(r) => (r, true),
            Reach::Silent => ((0..self.meters.len()).collect(), false),
        };
        let answers = reached
            .into_iter()
            .filter_map(|i| {
                let m = &mut self.meters[i];
                let answer = act(m);
                match m.behaviour {
                    Behaviour::Normal => Some(answer),
                    Behaviour::Silent => None,
                    Behaviour::Garbage => Some(m.garbage()),
                }
            })
            .collect();
        if answering {
            heard(answers)
        } else {
            Vec::new()
        }
    }

    /// Select by secondary address: the meters that match are selected and answer E5; the
    /// others are deselected.
    fn select(&mut self, mask: &[u8]) -> Vec<u8> {
        let answers = self
            .meters
            .iter_mut()
            .filter_map(|m| {
                m.selected = wire::selects(mask, &m.secondary());
                match (m.selected, m.behaviour) {
                    (false, _) | (true, Behaviour::Silent) => None,
                    (true, Behaviour::Normal) => Some(vec![E5]),
                    (true, Behaviour::Garbage) => Some(m.garbage()),
                }
            })
            .collect();
        heard(answers)
    }
}

/// What the master hears from these answers.
fn heard(mut answers: Vec<Vec<u8>>) -> Vec<u8> {
    match answers.len() {
        0 => Vec::new(),
        1 => answers.pop().unwrap_or_default(),
        _ => wire::collide(&answers),
    }
}

#[cfg(test)]
#[path = "segment_tests.rs"]
mod tests;
