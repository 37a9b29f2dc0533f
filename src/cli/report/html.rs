//! HTML building blocks of the report: escaping, numbers, embedded
//! pictures, sortable tables and the page around them. Everything the page
//! needs is inline (styles, the sort script, pictures as data: URIs), and a
//! Content-Security-Policy forbids any other source, so the file opens the
//! same offline, mailed, or archived years later.

use std::fmt::Write as _;

/// Escapes text for HTML element content and quoted attribute values:
/// every string that came from an input goes through here.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

/// Standard base64 (RFC 4648, padded), for data: URIs; small enough not to
/// be worth a dependency.
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= chunk.len() {
                out.push(A[(n >> shift) as usize & 63] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// An `<img>` of PNG bytes as a data: URI, with escaped alternative text.
pub fn png_img(bytes: &[u8], alt: &str, class: &str) -> String {
    format!(r#"<img class="{class}" alt="{}" src="data:image/png;base64,{}">"#, esc(alt), base64(bytes))
}

/// A number with `digits` decimals, or a dash for a missing or non-finite one.
pub fn num(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "–".to_string(),
    }
}

/// A fraction as a percentage with one decimal.
pub fn pct(v: Option<f64>) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{:.1} %", 100.0 * x),
        _ => "–".to_string(),
    }
}

/// Colour of a physical verdict, the same as the pictures' bands
/// (`plausible::explain::verdict_colour`), so a row and its picture match.
pub fn verdict_css(verdict: &str) -> &'static str {
    match verdict {
        "plausible" => "#28a046",
        "unstable" => "#f09614",
        "floating" => "#8c50c8",
        "intersecting" => "#dc1e1e",
        _ => "#777777",
    }
}

/// A coloured verdict label.
pub fn verdict_badge(verdict: &str) -> String {
    format!(r#"<span class="verdict" style="background:{}">{}</span>"#, verdict_css(verdict), esc(verdict))
}

/// One cell of a sortable table: the text shown and the key it sorts by
/// (numbers sort as numbers; a missing key sorts last).
pub struct Cell {
    pub html: String,
    pub key: String,
}

impl Cell {
    /// A number shown with `digits` decimals, sorted by its full value.
    pub fn num(v: Option<f64>, digits: usize) -> Cell {
        let key = v.filter(|x| x.is_finite()).map(|x| x.to_string()).unwrap_or_default();
        Cell { html: num(v, digits), key }
    }

    /// A count.
    pub fn int(v: Option<u64>) -> Cell {
        Cell { html: v.map_or("–".into(), |x| x.to_string()), key: v.map(|x| x.to_string()).unwrap_or_default() }
    }

    /// Text from an input (escaped), sorted alphabetically.
    pub fn text(s: &str) -> Cell {
        Cell { html: esc(s), key: esc(s) }
    }

    /// Ready-made HTML with its own sort key.
    pub fn raw(html: String, key: &str) -> Cell {
        Cell { html, key: esc(key) }
    }
}

/// One table row: its id (for links), whether it is highlighted, its cells.
pub type Row = (Option<String>, bool, Vec<Cell>);

/// A table whose headers sort it when clicked (the inline script marks it
/// `data-sortable="ready"` once wired up). `row_ids` gives each row an id
/// (for links from pictures); `marked` rows are highlighted.
pub fn sortable_table(id: &str, headers: &[(&str, &str)], rows: &[Row]) -> String {
    let mut h = format!(r#"<table class="sortable" id="{}"><thead><tr>"#, esc(id));
    for (name, title) in headers {
        let _ = write!(h, r#"<th title="{}">{}</th>"#, esc(title), esc(name));
    }
    h.push_str("</tr></thead><tbody>");
    for (row_id, marked, cells) in rows {
        let id_attr = row_id.as_ref().map(|i| format!(r#" id="{}""#, esc(i))).unwrap_or_default();
        let class = if *marked { r#" class="marked""# } else { "" };
        let _ = write!(h, "<tr{id_attr}{class}>");
        for c in cells {
            let _ = write!(h, r#"<td data-v="{}">{}</td>"#, c.key, c.html);
        }
        h.push_str("</tr>");
    }
    h.push_str("</tbody></table>");
    h
}

const STYLE: &str = r#"
body{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif;margin:24px;color:#222;background:#fff;font-size:14px}
h1{font-size:22px;margin:0 0 4px} h2{font-size:18px;margin:28px 0 6px;border-bottom:2px solid #ddd;padding-bottom:3px}
h3{font-size:15px;margin:18px 0 6px} .note{color:#555;margin:4px 0 10px} .src{font-family:monospace;color:#555}
table{border-collapse:collapse;margin:6px 0 12px} th,td{border:1px solid #ccc;padding:3px 7px;text-align:right;white-space:nowrap}
th{background:#eef1f5;cursor:pointer;user-select:none;position:sticky;top:0}
.scroll{max-height:560px;overflow:auto;display:inline-block;border:1px solid #ccc;margin:6px 0 12px} .scroll table{margin:0} th[aria-sort=ascending]::after{content:" \25B2"} th[aria-sort=descending]::after{content:" \25BC"}
tbody tr:nth-child(even){background:#f7f8fa} tr.marked{outline:2px solid #3a6fd8} td:first-child{text-align:left}
.verdict{color:#fff;border-radius:3px;padding:1px 6px;font-size:12px}
.pics{display:flex;flex-wrap:wrap;gap:14px} figure{margin:0;border:1px solid #ddd;padding:6px;background:#fafafa}
figcaption{font-size:12px;color:#444;margin-top:4px;max-width:560px} img.big{max-width:100%;height:auto;display:block} img.half{max-width:560px;height:auto;display:block}
img.pose{width:200px;height:200px;display:block;image-rendering:auto}
.gallery{display:flex;flex-wrap:wrap;gap:10px} .card{border:1px solid #ccc;padding:6px;width:200px;background:#fafafa;font-size:12px}
.card .p{font-size:16px;font-weight:bold} .textpose{height:200px;display:flex;align-items:center;justify-content:center;color:#666;border:1px dashed #bbb;text-align:center;padding:4px}
.charts{display:flex;flex-wrap:wrap;gap:16px} svg text{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif}
.kv td:first-child{font-weight:bold;background:#f3f3f3}
"#;

/// Sorts a table by a clicked header (toggling the direction), numbers as
/// numbers and missing values last; marks every table it wired up.
const SCRIPT: &str = r#"
(function(){
  function key(td){var v=td.getAttribute('data-v');if(v===null||v==='')return null;var n=Number(v);return isFinite(n)?n:v;}
  function cmp(a,b){if(a===null)return b===null?0:1;if(b===null)return -1;
    if(typeof a==='number'&&typeof b==='number')return a-b;return String(a).localeCompare(String(b));}
  var tables=document.querySelectorAll('table.sortable');
  Array.prototype.forEach.call(tables,function(t){
    var ths=t.tHead.rows[0].cells, body=t.tBodies[0];
    Array.prototype.forEach.call(ths,function(th,i){
      th.addEventListener('click',function(){
        var asc=th.getAttribute('aria-sort')!=='ascending';
        Array.prototype.forEach.call(ths,function(h){h.removeAttribute('aria-sort');});
        th.setAttribute('aria-sort',asc?'ascending':'descending');
        var rows=Array.prototype.slice.call(body.rows);
        rows.sort(function(a,b){var x=key(a.cells[i]),y=key(b.cells[i]);
          if(x===null||y===null)return cmp(x,y);return asc?cmp(x,y):cmp(y,x);});
        rows.forEach(function(r){body.appendChild(r);});
      });
    });
    t.setAttribute('data-sortable','ready');
    t.setAttribute('data-rows',String(body.rows.length));
  });
  document.body.setAttribute('data-report','ready');
})();
"#;

/// The whole page around the sections' HTML.
pub fn page(title: &str, subtitle: &str, body: &str) -> String {
    format!(
        r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{}</title><style>{STYLE}</style></head>
<body><h1>{}</h1><p class="note">{}</p>
{body}
<script>{SCRIPT}</script>
</body></html>
"#,
        esc(title),
        esc(title),
        esc(subtitle)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_markup_and_quotes() {
        assert_eq!(esc(r#"<script>"a"&'b'"#), "&lt;script&gt;&quot;a&quot;&amp;&#39;b&#39;");
    }

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (raw, enc) in
            [("", ""), ("f", "Zg=="), ("fo", "Zm8="), ("foo", "Zm9v"), ("foob", "Zm9vYg=="), ("fooba", "Zm9vYmE="), ("foobar", "Zm9vYmFy")]
        {
            assert_eq!(base64(raw.as_bytes()), enc);
        }
    }
}
