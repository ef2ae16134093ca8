"""lead_report puts its section into tt-identify's report.md exactly once."""

from tt_prediction.lead_report import SECTION_BEGIN, SECTION_END, embed_in_report


def _section(body):
    return f'{SECTION_BEGIN}\n## Hit-point error against lead time\n\n{body}\n{SECTION_END}\n'


def test_section_is_appended_then_replaced_not_duplicated(tmp_path):
    report = tmp_path / 'report.md'
    original = '# Identification report\n\n## Plots\n\n![rebound](rebound.png)\n'
    report.write_text(original)
    embed_in_report(str(report), _section('first run'))
    embed_in_report(str(report), _section('second run'))
    text = report.read_text()
    assert text.startswith(original)
    assert text.count(SECTION_BEGIN) == 1 and text.count(SECTION_END) == 1
    assert 'second run' in text and 'first run' not in text
    assert not (tmp_path / 'report.md.tmp').exists()


def test_text_after_the_section_is_kept(tmp_path):
    report = tmp_path / 'report.md'
    report.write_text('# R\n\n' + _section('old') + '\n## Later\n')
    embed_in_report(str(report), _section('new'))
    text = report.read_text()
    assert 'old' not in text and 'new' in text and text.rstrip().endswith('## Later')
